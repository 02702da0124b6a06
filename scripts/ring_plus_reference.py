#!/usr/bin/env python3
"""A numpy transcription of the reference RING++ (Xu, Lu et al., "RING++: Roto-Translation
Invariant Gram for Global Localization on a Sparse Scan Map", T-RO 2023), from
lus6-Jenny/RING: `utils/core.py` `generate_bev_feats`, `utils/extract_local_descriptor.py`
`build_neighbors_NN`, the CUDA kernels `calculate_features` and `point2gridmap` of
`utils/generate_bev_pointfeat_cython`, the KITTI loader's `read_pc` + `normalize_pc`; the
Radon transform, distance and pose of `ring_reference.py` (RING's CPU path) on each of the six
feature grids. The cross-check of toporec's `ring-plus`.

Prints, per cloud:
  `path,ringplus,<6 x 14400 values>`      the six translation-invariant sinograms
  `path,ringplusgrid,<6 x 14400 values>`  the six feature grids ([feature][x cell][y cell])
  `path,ringpluspose,<yaw deg>,<dx m>,<dy m>,<distance>,<shift>,<x cells>,<y cells>` for each of
  the queries of `ring_reference.QUERIES` made from the cloud.

Where this differs from the reference (as toporec does): the feature grids' Radon transform is
skimage's at RING's CPU angles (3 degrees apart, no endpoint) where the reference's GPU path uses
torch-radon (120 angles over [0, 2 pi] with the endpoint); the kernel's per-cell maximum (a race
between GPU threads) is the true maximum; the neighbourhoods' covariance, eigenvalues and
features are float64 where the reference's are float32.

Run: `python3 scripts/ring_plus_reference.py FILE...`; needs numpy, scikit-image and
scikit-learn.
"""
import sys

import numpy as np
from sklearn.neighbors import NearestNeighbors

from baselines_reference import load
from ring_reference import N, QUERIES, instance_norm, moved, tiring

BOUND, GROUND, Z_SCALE, K = 70.0, -1.0, 10.0, 30


def scaled_cloud(pts):
    """KITTIPointCloudLoader.read_pc (origin points, ground, duplicates) + normalize_pc."""
    pts = pts[~np.all(np.isclose(pts, 0), axis=1)]
    pts = pts[pts[:, 2] > GROUND]
    pts = np.unique(pts, axis=0)
    pc = np.array(pts, dtype=np.float32)
    mask = (np.abs(pc[:, 0]) < np.float32(BOUND)) & (np.abs(pc[:, 1]) < np.float32(BOUND))
    mask &= (pc[:, 2] > np.float32(GROUND)) & (pc[:, 2] < np.float32(Z_SCALE))
    pc = pc[mask]
    pc[:, 0] = pc[:, 0] / np.float32(BOUND)
    pc[:, 1] = pc[:, 1] / np.float32(BOUND)
    pc[:, 2] = pc[:, 2] / np.float32(Z_SCALE)
    return pc


def features(pc):
    """Columns 0, 1, 3, 10, 11, 12 of `calculate_features` from the 30 nearest neighbours."""
    x = pc.astype(np.float64)
    k = min(K, len(x))
    idx = NearestNeighbors(n_neighbors=k, algorithm="kd_tree").fit(x).kneighbors(x)[1]
    nb = x[idx]  # n x k x 3
    p = nb - nb.mean(axis=1, keepdims=True)
    cov = np.matmul(p.transpose(0, 2, 1), p) / (k - 1)
    l3 = np.linalg.eigvalsh(cov)[:, ::-1]
    l2 = np.linalg.eigvalsh(cov[:, :2, :2])[:, ::-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = l3.sum(axis=1)
        change = l3[:, 2] / s
        omni = np.power(l3.prod(axis=1) / s ** 3, 1.0 / 3.0)
        entropy = -((l3 / s[:, None]) * np.log(l3 / s[:, None])).sum(axis=1)
        lin2 = l2[:, 1] / l2[:, 0]
    z = nb[:, :, 2]
    dz = z.max(axis=1) - z.min(axis=1)
    vz = ((z - z.mean(axis=1, keepdims=True)) ** 2).mean(axis=1)
    return np.stack([change, omni, entropy, lin2, dz, vz], axis=1)


def cell_index(v):
    """point2gridmap's index: float coordinate, double arithmetic, gap stored as a float."""
    v = v.copy()
    v[v == 0] = np.float32(0.0001)
    v[v > 1] = np.float32(0.9999)
    v[v < -1] = np.float32(-0.9999)
    gap = float(np.float32(2.0 / N))
    return np.floor((v.astype(np.float64) + 1.0) / gap).astype(int)


def grids(pc, f):
    """Per cell and feature the largest value, 0 when none is larger; NaN never wins."""
    ix, iy = cell_index(pc[:, 0]), cell_index(pc[:, 1])
    out = np.zeros((f.shape[1], N, N))
    vals = np.where(np.isnan(f), -np.inf, f)
    for c in range(f.shape[1]):
        np.maximum.at(out[c], (ix, iy), vals[:, c])
    return out


def describe(pts):
    pc = scaled_cloud(pts)
    g = grids(pc, features(pc))
    return np.stack([tiring(c) for c in g]), g


def distance(q, m):
    """circorr2 over six channels: per channel instance norm, magnitudes summed."""
    corr = np.zeros(N)
    for a, b in zip(q, m):
        fa = np.fft.fft(instance_norm(a), axis=0, norm="ortho")
        fb = np.fft.fft(instance_norm(b), axis=0, norm="ortho")
        c = np.fft.ifft(fa * np.conj(fb), axis=0, norm="ortho")
        corr += np.sqrt(c.real ** 2 + c.imag ** 2 + 1e-15).sum(axis=1)
    score = corr.max() / (0.15 * len(q) * N * N)
    shift = N // 2 - int(np.argmax(np.fft.fftshift(corr)))
    return 1.0 - score, shift


def rotate(imgs, degrees):
    """torchvision's rotate of a C x H x W tensor: nearest, about the centre, zeros."""
    th = np.radians(degrees)
    c, s = np.cos(th), np.sin(th)
    out = np.zeros_like(imgs)
    for i in range(N):
        yc = i - (N - 1) / 2.0
        for j in range(N):
            xc = j - (N - 1) / 2.0
            gx = (c * xc - s * yc) / (0.5 * N)
            gy = (s * xc + c * yc) / (0.5 * N)
            ix = np.rint(((gx + 1) * N - 1) / 2.0)
            iy = np.rint(((gy + 1) * N - 1) / 2.0)
            if 0 <= ix < N and 0 <= iy < N:
                out[:, i, j] = imgs[:, int(iy), int(ix)]
    return out


def solve_translation(a, b):
    """Normalized together (mean, unbiased std), 2-D correlation per channel, summed."""
    a = (a - a.mean()) / a.std(ddof=1)
    b = (b - b.mean()) / b.std(ddof=1)
    fa = np.fft.fft2(a, axes=(-2, -1), norm="ortho")
    fb = np.fft.fft2(b, axes=(-2, -1), norm="ortho")
    c = np.fft.ifft2(fa * np.conj(fb), axes=(-2, -1), norm="ortho")
    corr = np.fft.fftshift(np.sqrt(c.real ** 2 + c.imag ** 2).sum(axis=0))
    r, col = np.unravel_index(int(np.argmax(corr)), corr.shape)
    return N // 2 - int(r), N // 2 - int(col), -float(corr.max())


def pose(q_g, m_g, shift):
    x, y, err = solve_translation(rotate(q_g, shift * 360.0 / N), m_g)
    extra = shift - N // 2
    xe, ye, err_e = solve_translation(rotate(q_g, extra * 360.0 / N), m_g)
    return (x, y) if err < err_e else (xe, ye)


if __name__ == "__main__":
    for path in sys.argv[1:]:
        pts = load(path)
        m, m_g = describe(pts)
        print(path + ",ringplus," + ",".join(repr(float(v)) for v in m.ravel()))
        print(path + ",ringplusgrid," + ",".join(repr(float(v)) for v in m_g.ravel()))
        for yaw, dx, dy in QUERIES:
            q, q_g = describe(moved(pts, yaw, dx, dy))
            d, shift = distance(q, m)
            x, y = pose(q_g, m_g, shift)
            print(f"{path},ringpluspose,{yaw!r},{dx!r},{dy!r},{float(d)!r},{shift},{x},{y}")
