#!/usr/bin/env python3
"""Small numpy transcriptions of the reference ScanContext (irapkaist/scancontext C++,
`Scancontext.cpp`) and M2DP (LiHeUA/M2DP, `M2DP.m` + `CountVote2D.c`), the cross-check of
toporec's own. Reads clouds (KITTI `.bin`, NCLT `velodyne_sync` `.bin`, or CSV x,y,z) and prints,
per cloud, one CSV line: `path,scancontext,<1200 values>` and `path,m2dp,<192 values>`, plus
`path,scdist,<distance>,<shift>` of the cloud against itself turned by 42 degrees.

The descriptors are computed on the points as given (no voxel grid), with the reference
parameters: 20 rings x 60 sectors, 80 m, lidar height 2 m; M2DP 4 x 16 planes, 16 x 8 bins.
Sign conventions for M2DP as toporec documents them (PCA axes: largest-magnitude component
positive; singular vectors: the left one sums to >= 0).

Run: `python3 scripts/baselines_reference.py FILE...`; needs numpy.
"""
import math
import sys

import numpy as np


def load(path):
    if path.endswith(".csv"):
        return np.loadtxt(path, delimiter=",", skiprows=1)
    raw = np.fromfile(path, dtype=np.uint8)
    if "velodyne_sync" in path:
        rec = raw.reshape(-1, 8)
        xyz = rec[:, :6].copy().view("<u2").astype(np.float64) * 0.005 - 100.0
        return np.stack([xyz[:, 0], -xyz[:, 1], -xyz[:, 2]], axis=1)
    pts = raw.view("<f4").reshape(-1, 4)[:, :3].astype(np.float64)
    keep = np.isfinite(pts).all(axis=1) & ~(pts == 0).all(axis=1)
    return pts[keep]


# --- ScanContext (C++) ---------------------------------------------------------------
RINGS, SECTORS, MAX_R, HEIGHT = 20, 60, 80.0, 2.0


def div(a, b):
    """IEEE division as in C++ (x / 0 is +-inf, not an exception)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.float64(a) / np.float64(b))


def xy2theta(x, y):
    if x >= 0 and y >= 0:
        return math.degrees(math.atan(div(y, x)))
    if x < 0 and y >= 0:
        return 180 - math.degrees(math.atan(div(y, -x)))
    if x < 0 and y < 0:
        return 180 + math.degrees(math.atan(div(y, x)))
    return 360 - math.degrees(math.atan(div(-y, x)))


def scancontext(pts):
    desc = np.full((RINGS, SECTORS), -1000.0)
    for x, y, z in pts:
        z = z + HEIGHT
        r = math.sqrt(x * x + y * y)
        if r > MAX_R:
            continue
        theta = 0.0 if r == 0 else xy2theta(x, y)
        ring = max(min(math.ceil(r / MAX_R * RINGS), RINGS), 1)
        sector = max(min(math.ceil(theta / 360.0 * SECTORS), SECTORS), 1)
        desc[ring - 1, sector - 1] = max(desc[ring - 1, sector - 1], z)
    desc[desc == -1000.0] = 0.0
    return desc.astype(np.float32)


def circshift(m, s):
    return np.roll(m, s, axis=-1)


def dist_direct(a, b):
    num, total = 0, 0.0
    for c in range(a.shape[1]):
        ca, cb = a[:, c].astype(np.float64), b[:, c].astype(np.float64)
        na, nb = np.linalg.norm(ca), np.linalg.norm(cb)
        if na == 0 or nb == 0:
            continue
        total += ca.dot(cb) / (na * nb)
        num += 1
    return 1.0 - total / num if num else 1.0


def sc_distance(a, b):
    ka, kb = a.astype(np.float64).mean(axis=0), b.astype(np.float64).mean(axis=0)
    best, arg = math.inf, 0
    for s in range(SECTORS):
        d = np.linalg.norm(ka - circshift(kb, s))
        if d < best:
            best, arg = d, s
    radius = round(0.5 * 0.1 * SECTORS)
    space = sorted({(arg + i) % SECTORS for i in range(-radius, radius + 1)})
    best_d, best_s = math.inf, arg
    for s in space:
        d = dist_direct(a, circshift(b, s))
        if d < best_d:
            best_d, best_s = d, s
    return best_d, best_s


# --- M2DP (MATLAB) --------------------------------------------------------------------
def m2dp(pts):
    data = pts - pts.mean(axis=0)
    w, v = np.linalg.eigh(data.T @ data)
    order = np.argsort(-w, kind="stable")
    axes = v[:, order].T
    for k in range(3):
        j = int(np.argmax(np.abs(axes[k])))
        if axes[k, j] < 0:
            axes[k] = -axes[k]
    data = data @ axes.T
    max_rho = math.sqrt((data ** 2).sum(axis=1).max())
    rho_edges = (np.arange(9) / 8.0) ** 2 * max_rho
    rho_edges[-1] += 0.001
    theta_edges = np.linspace(-math.pi, math.pi, 17)
    a = np.zeros((64, 128))
    for ip, az in enumerate(np.linspace(-math.pi / 2, math.pi / 2, 4)):
        for iq, el in enumerate(np.linspace(0, math.pi / 2, 16)):
            n = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
            h = n[0]
            px = np.array([1.0, 0, 0]) - h * n
            py = np.cross(n, px)
            u, vv = data @ px, data @ py
            theta, rho = np.arctan2(vv, u), np.sqrt(u * u + vv * vv)
            i = np.minimum(np.searchsorted(theta_edges[1:-1], theta, side="right"), 15)
            j = np.minimum(np.searchsorted(rho_edges[1:-1], rho, side="right"), 7)
            np.add.at(a[ip * 16 + iq], j * 16 + i, 1.0)
    a /= len(data)
    uu, s, vt = np.linalg.svd(a)
    u1, v1 = uu[:, 0], vt[0]
    if u1.sum() < 0:
        u1, v1 = -u1, -v1
    return np.concatenate([u1, v1]).astype(np.float32)


def turned(pts, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1], pts[:, 2]], axis=1)


if __name__ == "__main__":
    for path in sys.argv[1:]:
        pts = load(path)
        sc = scancontext(pts)
        print(path + ",scancontext," + ",".join(repr(float(x)) for x in sc.ravel()))
        print(path + ",m2dp," + ",".join(repr(float(x)) for x in m2dp(pts)))
        d, s = sc_distance(scancontext(turned(pts, 42.0)), sc)
        print(f"{path},scdist,{float(d)!r},{int(s)}")
