#!/usr/bin/env python3
"""A small numpy transcription of the reference Scan Context++ (gisbi-kim/scancontext_tro,
MATLAB: `tro2022/scancontext/desc/ptcloud2polarcontextAug.m`, `ptcloud2cartcontext.m`,
`sc2invkey.m`, `sc2vkey.m`, `alg/alignUsingSectorKey.m`, `alg/sc_dist_fast.m`), the cross-check
of toporec's own. Reads clouds (KITTI `.bin`, NCLT `velodyne_sync` `.bin`, or CSV x,y,z) and
prints, per cloud:

* `path,pp-polar,<3 x 1200 values>`: the polar contexts (20 rings x 60 sectors, 80 m, lidar
  height 1.9 m, bins of fewer than 5 points empty) seen from the sensor and from origins moved
  2 m to either side, float32;
* `path,pp-cart,<1600 values>`: the Cartesian context (40 x 40 bins of 5 m x 2 m, to 100 m
  along x and 40 m along y), float32;
* `path,pp-polardist,<distance>,<shift>`: the cloud turned by 42 degrees against itself;
* `path,pp-cartdist,<distance>,<shift>,<reversed>`: the cloud turned by 180 degrees against
  itself, the query also compared turned round.

No voxel grid (the voxel grids of MATLAB, PCL and toporec place their cells differently).
Two departures from the MATLAB code, both toporec's documented choices, following the paper:
the Cartesian bins are even, floor((x + x_max) / x_unit), where `ptcloud2cartcontext.m` folds
(-x_unit, x_unit) into one bin; and each shift around the sector-key alignment is tried from the
unshifted query, where `sc_dist_fast.m` accumulates them and shifts the other way.

Run: `python3 scripts/scancontext_pp_reference.py FILE...`; needs numpy.
"""
import math
import sys

import numpy as np

from baselines_reference import load, turned, xy2theta

RINGS, SECTORS, MAX_R, HEIGHT, MIN_POINTS, SHIFT = 20, 60, 80.0, 1.9, 5, 2.0
X_MAX, Y_MAX, X_UNIT, Y_UNIT = 100.0, 40.0, 5.0, 2.0
SEARCH_RATIO = 0.1


def polar(pts, origin):
    gap, angle = MAX_R / RINGS, 360.0 / SECTORS
    bins = {}
    for x, y, z in pts:
        x, y, z = x - origin[0], y - origin[1], z + HEIGHT
        if x == 0 and y == 0:
            continue  # atan(0/0) is NaN: the MATLAB index fails and the point is skipped
        r = math.sqrt(x * x + y * y)
        ring = math.floor(r / gap)
        ring = RINGS if ring >= RINGS else ring + 1
        sector = math.ceil(xy2theta(x, y) / angle)
        if sector == 0:
            sector = 1
        elif sector > SECTORS or sector < 1:
            sector = SECTORS
        bins.setdefault((ring - 1, sector - 1), []).append(z)
    img = np.zeros((RINGS, SECTORS))
    for (i, j), zs in bins.items():
        if len(zs) >= MIN_POINTS:
            img[i, j] = max(zs)
    return img


def polar_aug(pts):
    origins = [(0.0, 0.0), (0.0, -SHIFT), (0.0, SHIFT)]
    return [polar(pts, o).astype(np.float32) for o in origins]


def cart(pts):
    num_x, num_y = round(2 * X_MAX / X_UNIT), round(2 * Y_MAX / Y_UNIT)
    img = np.zeros((num_x, num_y))
    for x, y, z in pts:
        if x == 0 or y == 0 or not (-X_MAX < x < X_MAX) or not (-Y_MAX < y < Y_MAX):
            continue
        u = min(math.floor((x + X_MAX) / X_UNIT), num_x - 1)
        v = min(math.floor((y + Y_MAX) / Y_UNIT), num_y - 1)
        img[u, v] = max(img[u, v], z + HEIGHT)
    return img.astype(np.float32)


def direct(a, b):
    """1 - the mean cosine of the columns filled in both (sc_dist_fast's inner loop)."""
    sims = []
    for j in range(a.shape[1]):
        ca, cb = a[:, j], b[:, j]
        if not ca.any() or not cb.any():
            continue
        sims.append(float(ca @ cb) / (np.linalg.norm(ca) * np.linalg.norm(cb)))
    return 1.0 - sum(sims) / len(sims) if sims else 1.0


def sc_dist(q, c):
    """The distance and the shift s (query column (j + s) mod n against candidate column j)."""
    q, c = q.astype(np.float64), c.astype(np.float64)
    n = q.shape[1]
    kq, kc = q.mean(axis=0), c.mean(axis=0)
    coarse = min(range(n), key=lambda s: (float(np.sum((np.roll(kq, -s) - kc) ** 2)), s))
    radius = math.ceil(0.5 * SEARCH_RATIO * n)
    shifts = sorted({(coarse + i) % n for i in range(-radius, radius + 1)})
    return min((direct(np.roll(q, -s, axis=1), c), s) for s in shifts)


if __name__ == "__main__":
    for path in sys.argv[1:]:
        pts = load(path)
        contexts = polar_aug(pts)
        print(path + ",pp-polar," + ",".join(repr(float(v)) for c in contexts for v in c.ravel()))
        cc = cart(pts)
        print(path + ",pp-cart," + ",".join(repr(float(v)) for v in cc.ravel()))
        q = polar(turned(pts, 42.0), (0.0, 0.0)).astype(np.float32)
        d, s = min(sc_dist(q, c) for c in contexts)
        print(f"{path},pp-polardist,{float(d)!r},{s}")
        qc = cart(turned(pts, 180.0))
        d, s, rev = min((*sc_dist(qc, cc), 0), (*sc_dist(qc[::-1, ::-1], cc), 1))
        print(f"{path},pp-cartdist,{float(d)!r},{s},{rev}")
