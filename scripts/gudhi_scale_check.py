#!/usr/bin/env python3
"""Scales clouds by 2^k beyond the band toporec guarantees (|k| > 400) and checks, for each k,
that `toporec diagram` either gives GUDHI `precision='exact'`'s diagram of the same scaled
input (equal pair counts, pairs matched within 1e-12 relative) or refuses it with a one-line
error, exit code 2 — never a panic, never a different diagram. Exits 1 on any failure.

Run: `python3 scripts/gudhi_scale_check.py --toporec target/release/toporec CLOUD.csv...`
(the test suite runs it); needs `pip install gudhi numpy`.
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
from gudhi_crosscheck_lib import match, toporec_diagram  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--toporec", required=True)
ap.add_argument("--ks", default="-1000,-823,-650,-401,401,650,823,1000")
ap.add_argument("clouds", nargs="+")
args = ap.parse_args()

failures = 0
with tempfile.TemporaryDirectory() as tmp:
    for cloud in args.clouds:
        base = np.loadtxt(cloud, delimiter=",", skiprows=1)
        for k in map(int, args.ks.split(",")):
            pts = np.ldexp(base, k)
            path = os.path.join(tmp, "scaled.csv")
            np.savetxt(path, pts, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
            pts = np.loadtxt(path, delimiter=",", skiprows=1)
            out = subprocess.run([args.toporec, "diagram", path], capture_output=True, text=True)
            name = f"{os.path.basename(cloud)} k={k}"
            if out.returncode == 2:
                err = out.stderr.strip()
                ok = len(err.splitlines()) == 1 and "panicked" not in err and "2^" in err
                print(f"{name}: refused ({err}){'' if ok else ' -- NOT A CLEAN REFUSAL'}")
                failures += not ok
                continue
            if out.returncode != 0:
                print(f"{name}: exit {out.returncode}: {out.stderr.strip()}")
                failures += 1
                continue
            st = gudhi.AlphaComplex(points=pts, precision="exact").create_simplex_tree()
            st.compute_persistence()
            ref = [sorted(map(tuple, st.persistence_intervals_in_dimension(d).tolist())) for d in range(3)]
            worst = match(toporec_diagram(out.stdout), ref)
            counts = "/".join(str(len(x)) for x in ref)
            if worst is None:
                print(f"{name}: DIFFERENT from GUDHI exact ({counts})")
                failures += 1
            else:
                print(f"{name}: equal to GUDHI exact ({counts}), largest difference {worst:.1e}")
print(f"{failures} failure(s)")
sys.exit(1 if failures else 0)
