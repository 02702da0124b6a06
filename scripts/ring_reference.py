#!/usr/bin/env python3
"""A numpy transcription of the reference RING (Lu et al., "One RING to Rule Them All: Radon
Sinogram for Place Recognition, Orientation and Translation Estimation", IROS 2022; code
lus6-Jenny/RING: `utils/core.py` `generate_bev` + `generate_RING_cpu` (its CPU path),
`utils/vox_utils/vox.py` `voxelize_xyz`, `utils/circorr2.py` `circular_corr`,
`evaluation/evaluate.py` for the pose), the cross-check of toporec's `ring`.

Reads clouds (KITTI `.bin`, NCLT `velodyne_sync` `.bin`, or CSV x,y,z) and prints, per cloud:
  `path,ring,<14400 values>`     the translation-invariant sinogram (120 angles x 120 offsets)
  `path,ringbev,<occupied cells>` the flat indices (x cell * 120 + y cell) of the occupied cells
  `path,ringpose,<yaw deg>,<dx m>,<dy m>,<distance>,<shift>,<x cells>,<y cells>` for each of
      three queries made from the cloud (turned by yaw, then moved by (dx, dy)), against the cloud.

What the reference computes, step by step:
* The BEV: points with x, y in (-70, 70) m and z in (1, 20) m (raw metres, the sensor frame) on a
  120 x 120 grid (cell 140/120 m), occupancy 0/1. Cell coordinates are `x / vs - 0.5 + 60` written
  as the reference's 4x4 transform does (`x * (1/vs) + (1/vs) * (70 - vs/2)`), rounded half to
  even (`torch.round`); a point whose z cell coordinate is exactly 0, or within 0.1 cell of the
  sensor, is dropped; cell (0, 0) is always cleared (`voxels[base] = 0`). The image is indexed
  [x cell, y cell].
* The sinogram: skimage's `radon(bev, theta)` with theta = 120 angles over [0, 360) degrees (3
  degrees apart, no endpoint; circle=True, so the grid's corners outside the inscribed circle are
  lost), transposed to angles x offsets.
* The descriptor (TIRING): |FFT| of each angle's row along the offsets (norm "ortho").
* The distance: both descriptors instance-normalized (mean 0, biased variance, eps 1e-5), a
  circular cross-correlation along the angle axis per offset column (FFT, norm "ortho"), its
  magnitude (sqrt(re^2 + im^2 + 1e-15)) summed over the columns; score = max / (0.15 * 14400),
  distance = 1 - score; shift = 60 - argmax(fftshift(corr)) (the first maximum).
* The pose (`evaluate.py`): the query's BEV turned by shift * 3 degrees and by (shift - 60) * 3
  degrees (torchvision `rotate`: nearest cell, about the grid's centre, zeros outside), each
  matched to the map BEV by a 2-D circular cross-correlation (both normalized by mean and
  unbiased std, norm "ortho", magnitude, fftshift, the first maximum in row-major order):
  x = 60 - row, y = 60 - col cells; the angle with the larger peak wins.

Arithmetic is float64 throughout, where the reference computes the grid in float32 torch tensors
(a point within ~1e-5 m of a cell edge may fall in the neighbouring cell there) and passes theta
as float32 (its cosines then float32: the sinogram moves by up to ~2e-5 relative).

Run: `python3 scripts/ring_reference.py FILE...`; needs numpy and scikit-image.
"""
import math
import sys

import numpy as np
from skimage.transform import radon

from baselines_reference import load

N = 120  # cells a side, angles
BOUND = 70.0
Z_MIN, Z_MAX = 1.0, 20.0
THETA = np.linspace(0.0, 360.0, N, endpoint=False)


def bev(pts):
    vs = 2 * BOUND / N
    vz = Z_MAX - Z_MIN
    s, sz = 1.0 / vs, 1.0 / vz
    t, tz = s * (BOUND - vs / 2.0), sz * (-Z_MIN - vz / 2.0)
    x = pts[:, 0] * s + t
    y = pts[:, 1] * s + t
    z = pts[:, 2] * sz + tz
    keep = (x > -0.5) & (x < N - 0.5) & (y > -0.5) & (y < N - 0.5) & (z > -0.5) & (z < 0.5) & (z != 0.0)
    near = np.sqrt((t - x) ** 2 + (t - y) ** 2 + (tz - z) ** 2) < 0.1
    keep &= ~near
    xi = np.clip(np.round(x[keep]), 0, N - 1).astype(int)
    yi = np.clip(np.round(y[keep]), 0, N - 1).astype(int)
    img = np.zeros((N, N))
    img[xi, yi] = 1.0
    img[0, 0] = 0.0
    return img


def tiring(img):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "image must be zero outside the reconstruction circle"
        sino = radon(img, theta=THETA).T  # angles x offsets
    return np.abs(np.fft.fft(sino, axis=-1, norm="ortho"))


def instance_norm(a):
    return (a - a.mean()) / np.sqrt(a.var() + 1e-5)


def distance(q, m):
    a, b = instance_norm(q), instance_norm(m)
    fa, fb = np.fft.fft(a, axis=0, norm="ortho"), np.fft.fft(b, axis=0, norm="ortho")
    c = np.fft.ifft(fa * np.conj(fb), axis=0, norm="ortho")
    corr = np.sqrt(c.real ** 2 + c.imag ** 2 + 1e-15).sum(axis=1)
    score = corr.max() / (0.15 * N * N)
    shift = N // 2 - int(np.argmax(np.fft.fftshift(corr)))
    return 1.0 - score, shift


def rotate(img, degrees):
    """torchvision.transforms.functional.rotate(img, degrees): nearest, about the centre, zeros."""
    th = math.radians(degrees)
    c, s = math.cos(th), math.sin(th)
    h, w = img.shape
    out = np.zeros_like(img)
    for i in range(h):
        yc = i - (h - 1) / 2.0
        for j in range(w):
            xc = j - (w - 1) / 2.0
            gx = (c * xc - s * yc) / (0.5 * w)
            gy = (s * xc + c * yc) / (0.5 * h)
            ix = np.rint(((gx + 1) * w - 1) / 2.0)
            iy = np.rint(((gy + 1) * h - 1) / 2.0)
            if 0 <= ix < w and 0 <= iy < h:
                out[i, j] = img[int(iy), int(ix)]
    return out


def solve_translation(a, b):
    a = (a - a.mean()) / a.std(ddof=1)
    b = (b - b.mean()) / b.std(ddof=1)
    c = np.fft.ifft2(np.fft.fft2(a, norm="ortho") * np.conj(np.fft.fft2(b, norm="ortho")), norm="ortho")
    corr = np.fft.fftshift(np.sqrt(c.real ** 2 + c.imag ** 2))
    r, col = np.unravel_index(int(np.argmax(corr)), corr.shape)
    return N // 2 - int(r), N // 2 - int(col), -float(corr.max())


def pose(q_bev, m_bev, shift):
    x, y, err = solve_translation(rotate(q_bev, shift * 360.0 / N), m_bev)
    extra = shift - N // 2
    xe, ye, err_e = solve_translation(rotate(q_bev, extra * 360.0 / N), m_bev)
    return (x, y) if err < err_e else (xe, ye)


def moved(pts, yaw_deg, dx, dy):
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.stack([c * pts[:, 0] - s * pts[:, 1] + dx, s * pts[:, 0] + c * pts[:, 1] + dy, pts[:, 2]], axis=1)


QUERIES = [(42.0, 0.0, 0.0), (30.0, 3.5, -2.0), (180.0, 2.0, 1.0)]

if __name__ == "__main__":
    for path in sys.argv[1:]:
        pts = load(path)
        m_bev = bev(pts)
        m = tiring(m_bev)
        print(path + ",ring," + ",".join(repr(float(v)) for v in m.ravel()))
        print(path + ",ringbev," + ",".join(str(i) for i in np.flatnonzero(m_bev.ravel())))
        for yaw, dx, dy in QUERIES:
            q_bev = bev(moved(pts, yaw, dx, dy))
            d, shift = distance(tiring(q_bev), m)
            x, y = pose(q_bev, m_bev, shift)
            print(f"{path},ringpose,{yaw!r},{dx!r},{dy!r},{float(d)!r},{shift},{x},{y}")
