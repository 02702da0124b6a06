#!/usr/bin/env python3
"""Times GUDHI's AlphaComplex(points).create_simplex_tree() + compute_persistence() on CSV
clouds (header x,y,z), in GUDHI's default precision ('safe') and in precision='exact' (the
mode whose diagrams toporec reproduces). Prints
`name,safe_median_ms,safe_H0/H1/H2,exact_median_ms,exact_H0/H1/H2` per cloud. Used by
`cargo bench --bench alpha`; needs `pip install gudhi numpy`."""
import argparse
import os
import statistics
import sys
import time

try:
    import gudhi
    import numpy as np
except ImportError as e:  # the Rust bench prints this line and goes on
    sys.exit(f"gudhi/numpy not installed ({e}); pip install gudhi numpy")

ap = argparse.ArgumentParser()
ap.add_argument("--reps", type=int, default=3)
ap.add_argument("clouds", nargs="+")
args = ap.parse_args()


def timed(pts, precision):
    times = []
    for _ in range(args.reps):
        t0 = time.perf_counter()
        st = gudhi.AlphaComplex(points=pts, precision=precision).create_simplex_tree()
        st.compute_persistence()
        times.append((time.perf_counter() - t0) * 1e3)
    counts = "/".join(str(len(st.persistence_intervals_in_dimension(d))) for d in range(3))
    return f"{statistics.median(times):.1f},{counts}"


for path in args.clouds:
    pts = np.loadtxt(path, delimiter=",", skiprows=1)
    name = os.path.splitext(os.path.basename(path))[0]
    print(f"{name},{timed(pts, 'safe')},{timed(pts, 'exact')}", flush=True)
