#!/usr/bin/env python3
"""A small numpy transcription of the reference LiDAR-Iris (BigMoWangying/LiDAR-Iris:
`LidarIris/LidarIris.cpp`: GetIris, LogGaborFilter, LoGFeatureEncode, GetHammingDistance,
Compare with match mode 2), the cross-check of toporec's own. Reads clouds (KITTI `.bin`,
NCLT `velodyne_sync` `.bin`, or CSV x,y,z) and prints, per cloud:

- `path,iris,<72000 bytes>`: the 80 x 360 image, then the template (8 planes of 80 x 360
  bits: the real parts of the 4 scales, then the imaginary parts) and the mask (4 planes),
  each packed with numpy.packbits (first column in the highest bit);
- `path,irisdist,<distance>,<yaw>,<reversed>`: the cloud turned by 42 degrees about z against
  itself, then the next cloud of the list against this one.

As in the reference, row by row: image[r] = floor(range) (clamped to 79), column floor(atan2
in degrees + 180.5) (clamped to 359), bit ceil(z + 5) (clamped to 0..7); the log-Gabor filters
of 4 scales (wavelength 18, x1.6, sigma/f0 0.75) on each row's DFT, one-sided (the bins above
180 stay 0), the inverse DFT unscaled (OpenCV's idft without DFT_SCALE); the template bit is
set where a part is positive, the mask where the magnitude is below 1e-4. The match: phase
correlation of the two images for the column shift, then the least masked Hamming distance
over the shifts -2..+2 around it (the candidate's template and mask rolled); match mode 2 also
matches the query rolled by 180 columns, and keeps the forward match only if strictly better.

Where toporec's documented choices differ from the C++ code, this follows toporec's (see
`src/baselines/lidar_iris.rs`): float64 throughout (the C++ code uses float32); a part counts as
positive above 1e-6, not 0 (an exact zero's sign is rounding noise); the phase correlation is
the translation-only one the paper describes, its integer peak (FFTMatch first estimates an
image-plane rotation and scale, then truncates a sub-pixel peak); no comparable bit gives
distance 1 (the C++ code: NaN).

Run: `python3 scripts/lidar_iris_reference.py FILE...`; needs numpy.
"""
import sys

import numpy as np

from baselines_reference import load, turned

ROWS, COLS = 80, 360
NSCALE, MIN_WAVELENGTH, MULT, SIGMA_ON_F = 4, 18.0, 1.6, 0.75
SIGN_MARGIN, MASK_BELOW = 1e-6, 1e-4


def image(pts):
    img = np.zeros((ROWS, COLS), np.uint8)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    dis = np.sqrt(x * x + y * y)
    yaw = np.degrees(np.arctan2(y, x)) + 180.0
    row = np.clip(np.floor(dis), 0, ROWS - 1).astype(int)
    bit = np.clip(np.ceil(z + 5.0), 0, 7).astype(int)
    col = np.clip(np.floor(yaw + 0.5), 0, COLS - 1).astype(int)
    np.bitwise_or.at(img, (row, col), (1 << bit).astype(np.uint8))
    return img


def filters():
    radius = np.arange(COLS // 2 + 1) / float(COLS)
    radius[0] = 1.0
    out, wavelength = [], MIN_WAVELENGTH
    for _ in range(NSCALE):
        fo = 1.0 / wavelength
        h = np.zeros(COLS)
        h[: COLS // 2 + 1] = np.exp(-(np.log(radius / fo) ** 2) / (2.0 * np.log(SIGMA_ON_F) ** 2))
        h[0] = 0.0
        out.append(h)
        wavelength *= MULT
    return out


def encode(img):
    """Template (2*NSCALE*ROWS x COLS bools) and mask (NSCALE*ROWS x COLS bools)."""
    spectrum = np.fft.fft(img.astype(np.float64), axis=1)
    real, imag, mask = [], [], []
    for h in filters():
        y = np.fft.ifft(spectrum * h, axis=1) * COLS  # unscaled, as cv::idft
        real.append(y.real > SIGN_MARGIN)
        imag.append(y.imag > SIGN_MARGIN)
        mask.append(np.abs(y) < MASK_BELOW)
    return np.vstack(real + imag), np.vstack(mask)


def describe(pts):
    img = image(pts)
    t, m = encode(img)
    return img, t, m


def correlation_shift(query_img, cand_img):
    """Column shift of the query against the candidate at the phase correlation's peak."""
    q = np.fft.fft2(query_img.astype(np.float64))
    c = np.fft.fft2(cand_img.astype(np.float64))
    r = q * np.conj(c)
    m = np.abs(r)
    r = np.where(m > 0, r / np.where(m > 0, m, 1.0), 0)
    surface = np.fft.ifft2(r).real
    col = int(np.argmax(surface)) % COLS
    return col - COLS if col > COLS // 2 else col


def hamming(t1, m1, t2, m2, scale):
    """GetHammingDistance: t1/m1 (the candidate) rolled by each shift around `scale`."""
    best, bias = None, None
    for shift in range(scale - 2, scale + 3):
        t1s = np.roll(t1, shift, axis=1)
        m1s = np.roll(m1, shift, axis=1)
        mask = m1s | m2
        total = mask.size - int(mask.sum())
        diff = int(((t1s ^ t2) & ~mask).sum())
        d = 1.0 if total == 0 else diff / total
        if best is None or d < best:
            best, bias = d, shift
    return best, bias


def compare(query, cand):
    """Compare(img1 = candidate, img2 = query) in match mode 2: (distance, yaw, reversed)."""
    qi, qt, qm = query
    ci, ct, cm = cand
    cm2, qm2 = np.vstack([cm, cm]), np.vstack([qm, qm])
    d1, b1 = hamming(ct, cm2, qt, qm2, correlation_shift(qi, ci))
    qi_x, qt_x, qm_x = (np.roll(a, COLS // 2, axis=1) for a in (qi, qt, qm2))
    d2, b2 = hamming(ct, cm2, qt_x, qm_x, correlation_shift(qi_x, ci))
    if d1 < d2:
        return d1, b1 % COLS, 0
    return d2, (b2 + COLS // 2) % COLS, 1


def packed(img, t, m):
    return np.concatenate([img.ravel(), np.packbits(t, axis=1).ravel(), np.packbits(m, axis=1).ravel()])


if __name__ == "__main__":
    paths = sys.argv[1:]
    clouds = [load(p) for p in paths]
    descs = [describe(c) for c in clouds]
    for i, path in enumerate(paths):
        print(path + ",iris," + ",".join(str(int(v)) for v in packed(*descs[i])))
        d, yaw, rev = compare(describe(turned(clouds[i], 42.0)), descs[i])
        print(path + f",irisdist,{d!r},{yaw},{rev}")
        j = (i + 1) % len(paths)
        d, yaw, rev = compare(descs[j], descs[i])
        print(path + f",irispair,{d!r},{yaw},{rev}")
