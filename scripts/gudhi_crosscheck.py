#!/usr/bin/env python3
"""Cross-checks `toporec diagram` against GUDHI's AlphaComplex(precision='exact') on random
clouds of four kinds: generic (uniform), 5 mm-quantized (as NCLT stores scans), integer
lattices with duplicate points, and near-planar. For every cloud the pair counts per dimension
must be equal (the same pairing: toporec decides every comparison exactly, as GUDHI `exact`
does) and the pairs must match one to one with birth and death within 1e-12 relative (both
evaluate the values in floating point; they differ by a few ulps). Prints one line per cloud
with the largest relative difference, and exits 1 on any mismatch.

Run: `python3 scripts/gudhi_crosscheck.py --toporec target/release/toporec` (the test suite
runs it too); needs `pip install gudhi numpy`.
"""
import argparse
import os
import subprocess
import sys
import tempfile

try:
    import gudhi
    import numpy as np
except ImportError as e:
    sys.exit(f"gudhi/numpy not installed ({e}); pip install gudhi numpy")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from gudhi_crosscheck_lib import TOL, match, toporec_diagram  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--toporec", required=True, help="the toporec binary")
ap.add_argument("--clouds", type=int, default=40, help="clouds in all (split over the four kinds)")
ap.add_argument("--seed", type=int, default=2026)
args = ap.parse_args()


def cloud(kind, rng):
    n = int(rng.integers(200, 1200))
    if kind == "generic":
        return rng.random((n, 3)) * rng.choice([1.0, 50.0, 1e-3])
    if kind == "quantized":
        return np.round(rng.normal(scale=20.0, size=(n, 3)) / 0.005) * 0.005
    if kind == "lattice":
        pts = rng.integers(0, 7, size=(n, 3)).astype(float)
        return np.vstack([pts, pts[: n // 10]])  # duplicates
    if kind == "near_planar":
        pts = rng.random((n, 3))
        pts[:, 2] = pts[:, 0] * 0.3 + pts[:, 1] * 0.2 + rng.normal(scale=1e-6, size=n)
        return pts
    raise ValueError(kind)


def gudhi_exact(pts):
    st = gudhi.AlphaComplex(points=pts, precision="exact").create_simplex_tree()
    st.compute_persistence()
    return [sorted(map(tuple, st.persistence_intervals_in_dimension(d).tolist())) for d in range(3)]


def toporec(path):
    out = subprocess.run([args.toporec, "diagram", path], capture_output=True, text=True, check=True).stdout
    return toporec_diagram(out)


kinds = ["generic", "quantized", "lattice", "near_planar"]
rng = np.random.default_rng(args.seed)
failures = 0
with tempfile.TemporaryDirectory() as tmp:
    for i in range(args.clouds):
        kind = kinds[i % len(kinds)]
        pts = cloud(kind, rng)
        path = os.path.join(tmp, f"{i}.csv")
        np.savetxt(path, pts, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
        # GUDHI reads the same doubles the file holds.
        pts = np.loadtxt(path, delimiter=",", skiprows=1)
        ref, ours = gudhi_exact(pts), toporec(path)
        counts = "/".join(str(len(x)) for x in ref)
        worst = match(ours, ref)
        failures += worst is None
        status = f"ok, largest difference {worst:.1e}" if worst is not None else (
            f"DIFFERENT (toporec {'/'.join(str(len(x)) for x in ours)})")
        print(f"cloud {i:2} {kind:12} {len(pts):5} points, pairs {counts}: {status}", flush=True)
print(f"{args.clouds - failures} of {args.clouds} clouds match GUDHI exact (same pair counts, values within {TOL:g})")
sys.exit(1 if failures else 0)
