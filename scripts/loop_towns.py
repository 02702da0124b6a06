#!/usr/bin/env python3
"""Loop closure on reversed revisits, per simulated town: the table of docs/loops.md.

For each town seed and lap offset: one simulated session of two laps, the second driven the
other way (`toporec simulate --sessions 1 --laps 2 --lap-offset OFFSET --seed TOWN --sensor
hdl64 --azimuth-res 1.0 --rate 5 --format nclt`), indexed with the methods asked for at
pipelines/compare.toml's settings (without its `fov_` lines, which describe the sample's
HDL-32E), `toporec loops --exclude-seconds 10 --all`, a match true within 5 m.

Per drive and method: the laps' separation (the median distance from a second-lap scan to the
nearest first-lap scan, from the ground truth), the revisits (second-lap scans with a scan at
least 10 s earlier within 5 m), the separable recall (the share of revisits found at precision
1 with the best threshold for the drive itself), F1 max, and, for the methods with a default
threshold, precision and recall at it.

With --same, same-direction revisits instead: two sessions of one lap each (`--sessions 2
--laps 1`), a revisit a second-session scan with a first-session scan within 5 m.

    python3 scripts/loop_towns.py --towns 13 --offsets 0,5.5 [--methods toporec-plus,scancontext-pp]
        [--toporec PATH (default: toporec on the PATH, else target/release/toporec)] [--out out/towns] [--json out/towns.json]
"""

import argparse
import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys

ALL_METHODS = [
    "toporec", "toporec-plus", "scancontext", "scancontext-pp", "scancontext-pp-cart", "m2dp",
    "solid", "lidar-iris", "ring", "ring-plus",
]
WITH_DEFAULT = {"toporec-plus", "scancontext", "ring", "ring-plus"}
RADIUS = 5.0
EXCLUDE_S = 10.0


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: exit {p.returncode}\n{p.stderr}")
    return p


def pipeline(compare, data, index, methods, extra):
    """compare.toml with its paths, its methods and no fov_ lines; `extra` appended."""
    text = open(compare).read()
    text = re.sub(r'^index = .*$', f'index = "{index}"', text, flags=re.M)
    text = text.replace('"../samples/town/velodyne_data"', f'"{data}"')
    text = re.sub(r'^methods = .*$', "methods = " + json.dumps(methods), text, flags=re.M)
    text = "\n".join(l for l in text.splitlines() if not l.startswith("fov_"))
    return text + "\n" + extra


def poses(ground_truth):
    """Every scan's (x, y) by its id, `<session>/<utime>`, from the drive's ground-truth files."""
    out = {}
    for name in sorted(os.listdir(ground_truth)):
        session = name[len("groundtruth_"):-len(".csv")]
        with open(os.path.join(ground_truth, name)) as f:
            for row in csv.reader(f):
                out[f"{session}/{row[0]}"] = (float(row[1]), float(row[2]))
    return out


def drive_facts(ground_truth):
    """The revisits and the separation of a drive: with one session, its second lap against its
    first (a revisit: a scan at least 10 s earlier within 5 m); with two, the second against the
    first (a revisit: a scan of the first within 5 m)."""
    p = poses(ground_truth)
    ids = sorted(p, key=lambda i: (i.split("/")[0], int(i.split("/")[1])))
    sessions = sorted({i.split("/")[0] for i in ids})
    if len(sessions) == 1:
        half = len(ids) // 2
        first, second = ids[:half], ids[half:]
    else:
        first = [i for i in ids if i.startswith(sessions[0] + "/")]
        second = [i for i in ids if not i.startswith(sessions[0] + "/")]
    dist = lambda a, b: math.hypot(p[a][0] - p[b][0], p[a][1] - p[b][1])
    utime = lambda i: int(i.split("/")[1])
    near = sorted(min(dist(q, f) for f in first) for q in second)
    separation = near[len(near) // 2]
    if len(sessions) == 1:
        revisits = {q for q in second if any(
            utime(q) - utime(e) >= EXCLUDE_S * 1e6 and dist(q, e) <= RADIUS for e in ids if utime(e) < utime(q))}
    else:
        revisits = {q for q in second if any(dist(q, e) <= RADIUS for e in first)}
    return revisits, separation


def scores(rows, revisits):
    """Separable recall and F1 max over every threshold; rows: (query, distance, true m)."""
    rows = sorted(rows, key=lambda r: r[1])
    n = len(revisits)
    tp = fp = 0
    separable = None
    prev_tp = 0
    f1 = 0.0
    i = 0
    while i < len(rows):
        j = i
        while j < len(rows) and rows[j][1] == rows[i][1]:  # a tie is never split
            q, _, t = rows[j]
            if t is not None and t <= RADIUS:
                tp += q in revisits
            else:
                fp += 1
            j += 1
        if fp and separable is None:
            separable = prev_tp
        prev_tp = tp
        if tp:
            prec, rec = tp / (tp + fp), tp / n
            f1 = max(f1, 2 * prec * rec / (prec + rec))
        i = j
    if separable is None:
        separable = tp
    return separable / n if n else float("nan"), f1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--towns", required=True)
    ap.add_argument("--offsets", default="0")
    ap.add_argument("--methods", default=",".join(ALL_METHODS))
    ap.add_argument("--toporec", default=shutil.which("toporec") or "target/release/toporec")
    ap.add_argument("--out", default="out/towns")
    ap.add_argument("--same", action="store_true",
                    help="same-direction revisits: two sessions of one lap, the second against the first")
    ap.add_argument("--only", help="seek loops with these methods of the index alone")
    ap.add_argument("--json")
    ap.add_argument("--extra", default="", help="TOML appended to the pipeline (a method's settings)")
    ap.add_argument("--thresholds", default="",
                    help="method=D,… : thresholds given instead of the methods' defaults")
    ap.add_argument("--tag", default="", help="names the indexes apart when --extra differs")
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    compare = os.path.join(root, "pipelines/compare.toml")
    methods = a.methods.split(",")
    given = dict(kv.split("=") for kv in a.thresholds.split(",") if kv)
    out = os.path.abspath(a.out)
    results = []
    print(f"{'town':>5} {'offset':>6} {'sep m':>6} {'revisits':>8} {'method':<20} {'separable':>9} "
          f"{'F1 max':>7} {'accepted':>8} {'false':>5} {'recall@def':>10}")
    for town in a.towns.split(","):
        for offset in ["same"] if a.same else a.offsets.split(","):
            drive = ["--sessions", "2", "--laps", "1"] if a.same else \
                ["--sessions", "1", "--laps", "2", "--lap-offset", offset]
            data = os.path.join(out, f"sim-{town}-{offset}")
            if not os.path.isdir(data):
                run([a.toporec, "simulate", "-o", data] + drive + ["--seed", town, "--sensor", "hdl64",
                     "--azimuth-res", "1.0", "--rate", "5", "--format", "nclt"])
            revisits, sep = drive_facts(os.path.join(data, "ground_truth"))
            index = os.path.join(out, f"index-{town}-{offset}{a.tag}")
            toml = os.path.join(out, f"index-{town}-{offset}{a.tag}.toml")
            with open(toml, "w") as f:
                f.write(pipeline(compare, os.path.join(data, "velodyne_data"), index, methods, a.extra))
            run([a.toporec, "run", toml, "--no-progress"])
            for method in a.only.split(",") if a.only else methods:
                csv_out = os.path.join(out, f"loops-{town}-{offset}{a.tag}-{method}.csv")
                thr = [] if method in WITH_DEFAULT else ["--threshold", "1e-12"]  # --all: every match, none accepted
                if method in given:
                    thr = ["--threshold", given[method]]
                run([a.toporec, "loops", "--index", index, "--method", method, "--exclude-seconds",
                     str(EXCLUDE_S), "--all", "--no-progress", "-o", csv_out] + thr)
                rows, accepted, false, found = [], 0, 0, 0
                with open(csv_out) as f:
                    for r in csv.DictReader(f):
                        t = float(r["true_distance_m"]) if r["true_distance_m"] else None
                        rows.append((r["query_scan"], float(r["distance"]), t))
                        if r["accepted"] == "true":
                            accepted += 1
                            if t is None or t > RADIUS:
                                false += 1
                            elif r["query_scan"] in revisits:
                                found += 1
                separable, f1 = scores(rows, revisits)
                rec = found / len(revisits) if method in WITH_DEFAULT else None
                results.append(dict(town=int(town), offset=None if a.same else float(offset), separation_m=sep,
                                    revisits=len(revisits), method=method, separable=separable,
                                    f1_max=f1, accepted=accepted if rec is not None else None,
                                    false=false if rec is not None else None, recall_default=rec))
                d = lambda v, f: format(v, f) if v is not None else "-"
                print(f"{town:>5} {offset:>6} {sep:>6.2f} {len(revisits):>8} {method:<20} "
                      f"{separable:>9.3f} {f1:>7.3f} {d(results[-1]['accepted'], 'd'):>8} "
                      f"{d(results[-1]['false'], 'd'):>5} {d(rec, '.3f'):>10}", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
