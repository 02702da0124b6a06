"""The map of `toporec loops` on simulated drives with drifting odometry, scored against the truth.

For each town (a `toporec simulate` seed) it drives, as ROS 1 bags whose /odom and /tf drift:
* `reversed-1.5` and `reversed-3.5`: one session of two laps, the second the other way round,
  1.5 m and 3.5 m to the side of the first;
* `two-sessions`: two sessions of one lap each, the same way, each odometry in a frame of its own.

With `--false-loop-towns` it drives instead the towns of docs/loops.md's reversed-revisit table
with the most false matches at the threshold (73, 79 and 67, at their two lap offsets: the laps
1 m and 3.5 m apart), as that table does (HDL-64E at 1°, 5 scans a second), the odometry drifting
the same way. With `--revisit-drives` it drives the table's drives named (TOWN:OFFSET, or
TOWN:same for two sessions each in its own frame) the same way.

Then `toporec loops <bags> --exclude-seconds 10` makes the map, and this script reports, from the
truth `simulate` writes beside the bags (`truth/<session>.tum`):
* the odometry's ATE (RMSE of position after one rigid alignment per session: the odometry alone
  cannot know where one session lies from another) and the map's (one rigid alignment for all
  sessions together);
* the map's ATE after one similarity alignment (with scale), which sets the odometry's scale
  error aside;
* the loops kept in the map more than 5 m off, and those the map rejected, by their true distance.

    python3 scripts/map_towns.py --toporec target/release/toporec --seeds 101,102,103,104,105,106
    python3 scripts/map_towns.py --false-loop-towns [--odometry icp] [--threshold 0.3534]
    python3 scripts/map_towns.py --revisit-drives 179:0.69,179:5.19,179:same
"""

import argparse
import csv
import math
import os
import shutil
import subprocess
import tempfile

import numpy as np


def tum(path):
    """Rows of (time, x, y, z) of a TUM file."""
    return np.array([[float(w) for w in line.split()[:4]] for line in open(path) if line.strip()])


def aligned_rmse(pairs, with_scale=False):
    """The RMSE of the estimates' positions after one alignment (Umeyama) of all `pairs`
    (estimate, truth) of equal-length position arrays together: rigid, or with `with_scale` a
    similarity, which sets aside the odometry's scale error (no loop can see it)."""
    est = np.vstack([e for e, _ in pairs])
    ref = np.vstack([t for _, t in pairs])
    mu_e, mu_r = est.mean(0), ref.mean(0)
    centred_e, centred_r = est - mu_e, ref - mu_r
    u, sigma, vt = np.linalg.svd(centred_r.T @ centred_e)
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rotation = u @ d @ vt
    scale = np.trace(np.diag(sigma) @ d) / np.sum(centred_e ** 2) if with_scale else 1.0
    moved = scale * (rotation @ centred_e.T).T + mu_r
    return float(np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1))))


def run(argv):
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stderr}")
    return done.stderr


# The towns' drives: blocks of 40 m, HDL-32E, 2 scans a second.
TOWNS = ["--rate", "2", "--blocks", "3", "--block-size", "40"]
# The reversed-revisit table's drives (scripts/loop_towns.py): HDL-64E, 5 scans a second.
REVISITS = ["--rate", "5", "--sensor", "hdl64"]
# Its towns with the most false matches at the threshold, each at its two lap offsets.
FALSE_LOOP_TOWNS = [(73, "1.3"), (73, "5.8"), (79, "1.19"), (79, "5.69"), (67, "0"), (67, "4.54")]


def drive(toporec, seed, kind, scratch, drift, odometry="poses", verify=True, sensor=TOWNS, threshold=None):
    out = os.path.join(scratch, f"{seed}-{kind}")
    args = [toporec, "simulate", "-o", out, "--format", "bag", "--seed", str(seed), "--azimuth-res", "1.0",
            *sensor, "--drift-scale", str(drift[0]),
            "--drift-heading", str(drift[1]), "--drift-noise", str(drift[2])]
    if kind == "two-sessions":
        args += ["--sessions", "2", "--laps", "1", "--own-frames"]
    else:
        args += ["--sessions", "1", "--laps", "2", "--lap-offset", kind.split("-")[1]]
    run(args)
    sessions = sorted(f[:-4] for f in os.listdir(os.path.join(out, "bag")))
    bags = [os.path.join(out, "bag", f"{s}.bag") for s in sessions]
    loops = os.path.join(out, "loops.csv")
    summary = run([toporec, "loops", *bags, "--exclude-seconds", "10", "--index", os.path.join(out, "index"),
                   "-o", loops, "--no-progress", "--g2o", os.path.join(out, "graph.g2o"), "--odometry", odometry]
                  + ([] if verify else ["--no-verify"])
                  + ([] if threshold is None else ["--threshold", str(threshold)]))
    truth = {s: tum(os.path.join(out, "truth", f"{s}.tum")) for s in sessions}
    corrected = {s: tum(os.path.join(out, f"loops.{s}.tum")) for s in sessions}
    # The odometry: the graph's odometry edges chained from each session's first vertex.
    odometry = {s: odometry_of(os.path.join(out, "graph.toporec-plus.g2o"), truth, sessions, s) for s in sessions}
    odometry_ate = math.sqrt(np.mean([aligned_rmse([(odometry[s], truth[s][:, 1:])]) ** 2 for s in sessions]))
    map_ate = aligned_rmse([(corrected[s][:, 1:], truth[s][:, 1:]) for s in sessions])
    map_ate_scaled = aligned_rmse([(corrected[s][:, 1:], truth[s][:, 1:]) for s in sessions], with_scale=True)
    # Each loop's true distance: vertex v is scan v of the sessions in order.
    places = np.vstack([truth[s][:, 1:] for s in sessions])
    kept_far, passed_far, rejected = 0, 0, []
    with open(loops) as f:
        for row in csv.DictReader(f):
            q, m = int(row["query_vertex"]), int(row["matched_vertex"])
            apart = float(np.linalg.norm(places[q] - places[m]))
            if row["in_map"] == "true" and apart > 5.0:
                kept_far += 1
            if row["verified"] == "true" and apart > 5.0:
                passed_far += 1
            if row["in_map"] == "false":
                rejected.append(apart)
    kept = [line for line in summary.splitlines() if line.startswith("map (")]
    return odometry_ate, map_ate, map_ate_scaled, kept_far, passed_far, rejected, kept[0] if kept else summary


def odometry_of(graph, truth, sessions, session):
    """The session's odometry positions: the graph's vertices (the log's poses; a session in a
    frame of its own moved rigidly by its loops, which its own alignment undoes), vertex v being
    scan v of the sessions in order."""
    vertices = {}
    for line in open(graph):
        words = line.split()
        if words and words[0] == "VERTEX_SE3:QUAT":
            vertices[int(words[1])] = [float(w) for w in words[2:5]]
    first = sum(len(truth[s]) for s in sessions[: sessions.index(session)])
    return np.array([vertices[first + k] for k in range(len(truth[session]))])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--toporec", default=shutil.which("toporec") or "target/release/toporec")
    parser.add_argument("--seeds", default="101,102,103,104,105,106")
    parser.add_argument("--drift", default="0.02,0.05,0.005",
                        help="scale, heading (degrees a metre), noise per metre")
    parser.add_argument("--odometry", default="poses", choices=["poses", "icp"],
                        help="the map's steps: the log's odometry, or each aligned again by ICP")
    parser.add_argument("--no-verify", action="store_true",
                        help="loops unchecked by ICP: the map weighs the descriptor's own pose")
    parser.add_argument("--threshold", type=float,
                        help="toporec-plus's loop threshold instead of its default")
    parser.add_argument("--false-loop-towns", action="store_true",
                        help="the towns 73, 79 and 67 of the reversed-revisit table instead of --seeds")
    parser.add_argument("--revisit-drives",
                        help="drives of the reversed-revisit table instead of --seeds: TOWN:OFFSET "
                             "(the second lap reversed) or TOWN:same (two sessions), comma-separated")
    args = parser.parse_args()
    drift = [float(v) for v in args.drift.split(",")]
    if args.false_loop_towns:
        drives, sensor = [(seed, f"reversed-{offset}") for seed, offset in FALSE_LOOP_TOWNS], REVISITS
    elif args.revisit_drives:
        pairs = [d.split(":") for d in args.revisit_drives.split(",")]
        drives = [(int(town), "two-sessions" if kind == "same" else f"reversed-{kind}") for town, kind in pairs]
        sensor = REVISITS
    else:
        kinds = ["reversed-1.5", "reversed-3.5", "two-sessions"]
        drives, sensor = [(int(s), kind) for s in args.seeds.split(",") for kind in kinds], TOWNS
    print("| town | drive | odometry ATE m | map ATE m | ratio | map ATE with scale m | passed ICP > 5 m off | "
          "kept > 5 m off | rejected (true distance m) |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory() as scratch:
        for seed, kind in drives:
            odo, ate, scaled, far, passed, rejected, _ = drive(args.toporec, seed, kind, scratch, drift,
                                                               args.odometry, not args.no_verify, sensor,
                                                               args.threshold)
            shown = ", ".join(f"{r:.1f}" for r in sorted(rejected)) or "none"
            print(f"| {seed} | {kind} | {odo:.3f} | {ate:.3f} | {ate / odo:.3f} | {scaled:.3f} | {passed} | {far} | "
                  f"{shown} |", flush=True)


if __name__ == "__main__":
    main()
