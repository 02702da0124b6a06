#!/usr/bin/env python3
"""A small numpy transcription of the reference SOLiD (sparolab/solid: `cpp/src/solid.cpp`,
`cpp/include/solid_module.h`, `python/utils/solid.py`), the cross-check of toporec's own.
Reads clouds (KITTI `.bin`, NCLT `velodyne_sync` `.bin`, or CSV x,y,z) and prints, per cloud,
`path,solid,<100 values>` (40 range values then 60 azimuth values, float32) and
`path,soliddist,<distance>,<shift>`: the cloud turned by 42 degrees about z against itself.

The C++ settings: 40 range bins to 80 m, 60 azimuth bins, 32 elevation bins over the HDL-64E's
+2 / -24.8 degrees; points within 3 m or beyond 80 m dropped (3D distance); no voxel grid (the
voxel grids of PCL, Open3D and toporec differ in where their cells lie). Elevation bins are
clamped to [0, 31] (the C++ code truncates towards zero and indexes out of bounds below one bin
under the field of view; the Python code wraps negative bins). The yaw is the Python
reference's: the shift s minimising sum |a_q - roll(a_c, s)|.

Run: `python3 scripts/solid_reference.py FILE...`; needs numpy.
"""
import math
import sys

import numpy as np

from baselines_reference import load, turned

NUM_RANGE, NUM_ANGLE, NUM_HEIGHT = 40, 60, 32
FOV_U, FOV_D = 2.0, -24.8
MIN_D, MAX_D = 3.0, 80.0


def xy2theta(x, y):
    if x >= 0 and y >= 0:
        return math.degrees(math.atan(y / x))
    if x < 0 and y >= 0:
        return 180 - math.degrees(math.atan(y / -x))
    if x < 0 and y < 0:
        return 180 + math.degrees(math.atan(y / x))
    return 360 - math.degrees(math.atan(-y / x))


def solid(pts):
    d2 = np.sum(pts * pts, axis=1)
    pts = pts[(d2 > MIN_D * MIN_D) & (d2 < MAX_D * MAX_D)]
    gap_range = MAX_D / NUM_RANGE
    gap_angle = 360.0 / NUM_ANGLE
    gap_height = (FOV_U - FOV_D) / NUM_HEIGHT
    rh = np.zeros((NUM_RANGE, NUM_HEIGHT))
    ah = np.zeros((NUM_ANGLE, NUM_HEIGHT))
    for x, y, z in pts:
        x = 0.001 if x == 0.0 else x
        y = 0.001 if y == 0.0 else y
        dist = math.sqrt(x * x + y * y)
        phi = math.degrees(math.atan2(z, dist))
        ir = min(max(math.floor(dist / gap_range), 0), NUM_RANGE - 1)
        ia = min(max(math.floor(xy2theta(x, y) / gap_angle), 0), NUM_ANGLE - 1)
        ih = min(max(math.floor((phi - FOV_D) / gap_height), 0), NUM_HEIGHT - 1)
        rh[ir, ih] += 1
        ah[ia, ih] += 1
    w = rh.sum(axis=0)
    lo, hi = w.min(), w.max()
    w = (w - lo) / (hi - lo) if hi > lo else np.ones_like(w)
    return np.concatenate([rh @ w, ah @ w]).astype(np.float32)


def distance(q, c):
    a, b = q[:NUM_RANGE].astype(np.float64), c[:NUM_RANGE].astype(np.float64)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return 1.0 if na == 0 or nb == 0 else 1.0 - float(a @ b) / (na * nb)


def yaw_shift(q, c):
    a, b = q[NUM_RANGE:].astype(np.float64), c[NUM_RANGE:].astype(np.float64)
    return int(np.argmin([np.sum(np.abs(a - np.roll(b, s))) for s in range(NUM_ANGLE)]))


if __name__ == "__main__":
    for path in sys.argv[1:]:
        pts = load(path)
        desc = solid(pts)
        print(path + ",solid," + ",".join(repr(float(x)) for x in desc))
        q = solid(turned(pts, 42.0))
        print(path + f",soliddist,{float(distance(q, desc))!r},{yaw_shift(q, desc)}")
