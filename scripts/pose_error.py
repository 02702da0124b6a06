#!/usr/bin/env python3
"""The error of the relative poses in a `toporec query` CSV against NCLT-layout ground truth.

    python3 scripts/pose_error.py HITS.csv GROUNDTRUTH_DB.csv GROUNDTRUTH_QUERY.csv \
        [--nearest-among DB_SCANS_FOLDER]

For each query's top-1 hit with an estimated position (`x_m`, `y_m`), the ground truth is the
query scan's pose in the hit's sensor frame (x forward, y left, z up): NCLT's ground truth
(`utime, x, y, z, roll, pitch, yaw`, z down) seen with z up, positions (x, -y) and headings
-yaw. Prints the count, the median and the 95th percentile of the translation error (m) and
of the yaw error (degrees), the yaw taken as the turn that brings the query's view onto the
hit's (`yaw_deg`, minus the query's heading in the hit's frame). With `--nearest-among`, only
the queries whose top-1 is the nearest of the database's scans (the `<utime>.bin` files of that
folder) are counted.
"""

import argparse
import csv
import math
import os


def poses(path):
    """utime -> (x, y, heading) with z up."""
    out = {}
    with open(path) as f:
        for row in csv.reader(f):
            if len(row) >= 7:
                out[int(float(row[0]))] = (float(row[1]), -float(row[2]), -float(row[6]))
    return out


def utime(scan_id):
    return int(scan_id.rsplit("/", 1)[-1])


def percentile(values, q):
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("hits")
    parser.add_argument("db_groundtruth")
    parser.add_argument("query_groundtruth")
    parser.add_argument("--nearest-among", help="the database's scan folder: only queries whose top-1 is its nearest scan")
    args = parser.parse_args()
    db, queries = poses(args.db_groundtruth), poses(args.query_groundtruth)
    among = None
    if args.nearest_among:
        among = [int(n.split(".")[0]) for n in os.listdir(args.nearest_among) if n.split(".")[0].isdigit()]
    with open(args.hits) as f:
        rows = [r for r in csv.DictReader(f) if r["rank"] == "1"]
    translation, yaw_error = [], []
    for r in rows:
        if not r["x_m"]:
            continue
        q, m = queries[utime(r["query_id"])], db[utime(r["scan_id"])]
        if among is not None:
            nearest = min(among, key=lambda t: math.dist(db[t][:2], q[:2]))
            if nearest != utime(r["scan_id"]):
                continue
        dx, dy = q[0] - m[0], q[1] - m[1]
        c, s = math.cos(m[2]), math.sin(m[2])
        x, y = c * dx + s * dy, -s * dx + c * dy
        translation.append(math.hypot(float(r["x_m"]) - x, float(r["y_m"]) - y))
        if r["yaw_deg"]:
            heading = math.degrees(q[2] - m[2])
            yaw_error.append(abs((float(r["yaw_deg"]) + heading + 180.0) % 360.0 - 180.0))
    if not translation:
        raise SystemExit("no top-1 hit with an estimated position")
    print(
        f"{len(translation)} queries: translation error median {percentile(translation, 0.5):.3f} m, "
        f"p95 {percentile(translation, 0.95):.3f} m; yaw error median {percentile(yaw_error, 0.5):.2f}°, "
        f"p95 {percentile(yaw_error, 0.95):.2f}°"
    )


if __name__ == "__main__":
    main()
