"""The cost and accuracy of `toporec loops`'s ICP check.

Cost, on real scans (`--data`, the shared data folder):
* the city drive (154 HDL-64E frames, about 120k points each):
  `toporec loops city_drive/city --exclude-seconds 2`;
* the 48 KITTI scans, one session per sequence: `toporec loops kitti/sequences/00 … 10
  --exclude-seconds 0.05`.
Each command runs with the check (the default) and with `--no-verify`, `--runs` times each; a
check costs the difference of the medians over the matches checked (the accepted rows). The kept
loops (query, match) are listed in `--kept-out` so that two builds can be compared.

Accuracy, on simulated HDL-64E drives (no drift: the log's poses are the truth): for seeds `--seeds`, two
laps (the second reversed, 1.5 m aside) and two same-direction sessions, `toporec loops <bag>
--exclude-seconds 10`; each kept loop's relative pose (`rel_*`) against the truth's (the
query's true pose in the match's true frame). Prints the median and 95th percentile of the
translation error (m) and of the rotation error (degrees).

    python3 scripts/icp_bench.py --toporec target/release/toporec --data ../shared/data
"""

import argparse
import csv
import math
import os
import statistics
import subprocess
import tempfile
import time

import numpy as np


def run(argv):
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stderr}")
    return time.perf_counter() - start, done.stderr


def cost(toporec, name, sources, exclusion, scratch, runs):
    """(checks, ms a check, kept pairs) of one command."""
    index = os.path.join(scratch, f"{name}-index")
    table = os.path.join(scratch, f"{name}.csv")
    base = [toporec, "loops", *sources, "--exclude-seconds", exclusion, "--index", index, "--no-progress"]
    run(base + ["-o", table, "--no-verify"])  # the index, made once
    plain = statistics.median(run(base + ["-o", table, "--no-verify"])[0] for _ in range(runs))
    with open(table) as f:
        checks = sum(r["accepted"] == "true" for r in csv.DictReader(f))
    verified = statistics.median(run(base + ["-o", table])[0] for _ in range(runs))
    with open(table) as f:
        kept = sorted((r["query_scan"], r["matched_scan"]) for r in csv.DictReader(f) if r["verified"] == "true")
    return checks, plain, verified, kept


def quaternion_matrix(qx, qy, qz, qw):
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])


def euler_matrix(roll, pitch, yaw):
    """R = Rz(yaw) Ry(pitch) Rx(roll), as nalgebra's `euler_angles` reads a rotation."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def vertex_poses(path):
    """Vertex id -> (rotation, position) of a g2o file's `VERTEX_SE3:QUAT` lines."""
    out = {}
    for line in open(path):
        w = line.split()
        if w and w[0] == "VERTEX_SE3:QUAT":
            v = [float(x) for x in w[2:9]]
            out[int(w[1])] = (quaternion_matrix(*v[3:7]), np.array(v[0:3]))
    return out


def accuracy(toporec, seed, kind, scratch):
    """(translation error m, rotation error degrees) of each kept loop of one drive."""
    out = os.path.join(scratch, f"{seed}-{kind}")
    args = [toporec, "simulate", "-o", out, "--format", "bag", "--seed", str(seed), "--sensor", "hdl64",
            "--rate", "2", "--blocks", "3", "--block-size", "40"]
    if kind == "two-sessions":
        args += ["--sessions", "2", "--laps", "1"]
    else:
        args += ["--sessions", "1", "--laps", "2", "--lap-offset", "1.5"]
    run(args)
    sessions = sorted(f[:-4] for f in os.listdir(os.path.join(out, "bag")))
    bags = [os.path.join(out, "bag", f"{s}.bag") for s in sessions]
    table = os.path.join(out, "loops.csv")
    run([toporec, "loops", *bags, "--exclude-seconds", "10", "--index", os.path.join(out, "index"), "-o", table,
         "--no-progress", "--no-optimize", "--g2o", os.path.join(out, "graph.g2o")])
    # Without drift, the log's poses (the graph's vertices) are the truth.
    truth = vertex_poses(os.path.join(out, "graph.toporec-plus.g2o"))
    errors = []
    with open(table) as f:
        for r in csv.DictReader(f):
            if r["verified"] != "true":
                continue
            (rq, tq), (rm, tm) = truth[int(r["query_vertex"])], truth[int(r["matched_vertex"])]
            true_rotation, true_translation = rm.T @ rq, rm.T @ (tq - tm)
            found_rotation = euler_matrix(*(math.radians(float(r[c])) for c in
                                            ["rel_roll_deg", "rel_pitch_deg", "rel_yaw_deg"]))
            found_translation = np.array([float(r[c]) for c in ["rel_x", "rel_y", "rel_z"]])
            off = true_rotation.T @ found_rotation
            angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(off) - 1) / 2))))
            errors.append((float(np.linalg.norm(found_translation - true_translation)), angle))
    return errors


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--toporec", default="target/release/toporec")
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seeds", default="101,102,103")
    parser.add_argument("--skip-cost", action="store_true", help="only the accuracy on simulated drives")
    parser.add_argument("--kept-out", help="write the kept loops of the real drives here")
    args = parser.parse_args()
    kitti = os.path.join(args.data, "kitti", "sequences")
    drives = [] if args.skip_cost else [
        ("city drive", [os.path.join(args.data, "city_drive", "city")], "2"),
        ("KITTI scans", [os.path.join(kitti, s) for s in sorted(os.listdir(kitti))], "0.05"),
    ]
    kept_lines = []
    with tempfile.TemporaryDirectory() as scratch:
        print("| scans | checks | command, --no-verify s | command s | ms a check | kept |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, sources, exclusion in drives:
            checks, plain, verified, kept = cost(args.toporec, name.replace(" ", "-"), sources, exclusion,
                                                 scratch, args.runs)
            per_check = (verified - plain) / max(checks, 1) * 1e3
            print(f"| {name} | {checks} | {plain:.2f} | {verified:.2f} | {per_check:.0f} | {len(kept)} |", flush=True)
            kept_lines += [f"{name},{q},{m}" for q, m in kept]
        if args.kept_out:
            with open(args.kept_out, "w") as f:
                f.write("\n".join(kept_lines) + "\n")
        errors = []
        for seed in [int(s) for s in args.seeds.split(",")]:
            for kind in ["reversed-1.5", "two-sessions"]:
                errors += accuracy(args.toporec, seed, kind, scratch)
        translation = sorted(e[0] for e in errors)
        rotation = sorted(e[1] for e in errors)
        p95 = lambda v: v[min(len(v) - 1, int(0.95 * len(v)))]
        print(f"\nsimulated loops kept: {len(errors)}; translation error median {statistics.median(translation):.4f} m, "
              f"95th percentile {p95(translation):.4f} m; rotation error median {statistics.median(rotation):.3f}°, "
              f"95th percentile {p95(rotation):.3f}°")


if __name__ == "__main__":
    main()
