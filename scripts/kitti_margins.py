#!/usr/bin/env python3
"""How clearly each KITTI query of docs/evaluation.md has a nearest database scan.

    python3 scripts/kitti_margins.py [../shared/data/kitti/sequences]

The places evaluation on the shared KITTI scans takes frames 0 and 6 of each sequence (and 94
and 198 of sequence 00) as the database and frames 3 and 9 (95, 199) as queries, a query's
sequence its search space. For each query: its distance to each database scan of its sequence
(from the sequence's `poses.txt`, metres) and the margin, the second-nearest's distance less the
nearest's. Frame 3 lies between frames 0 and 6, so its margin is what decides, not the place.
"""

import math
import os
import sys

DATABASE = {0, 6}
QUERIES = [3, 9]
SEQUENCE_00 = ({94, 198}, [95, 199])


def positions(path):
    """Each frame's position (the translation column of its 3 × 4 pose)."""
    with open(path) as f:
        return [tuple(float(v) for v in (row[3], row[7], row[11])) for row in map(str.split, f) if row]


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/kitti/sequences"
    print(f"{'seq':>3} {'query':>5} {'nearest':>7} {'m':>6} {'next':>5} {'m':>6} {'margin m':>8}")
    for seq in sorted(os.listdir(root)):
        path = os.path.join(root, seq, "poses.txt")
        if not os.path.exists(path):
            continue
        at = positions(path)
        database, queries = set(DATABASE), list(QUERIES)
        if seq == "00":
            database |= SEQUENCE_00[0]
            queries += SEQUENCE_00[1]
        for q in queries:
            near = sorted((math.dist(at[q], at[d]), d) for d in database)
            (d1, f1), (d2, f2) = near[0], near[1]
            print(f"{seq:>3} {q:>5} {f1:>7} {d1:>6.2f} {f2:>5} {d2:>6.2f} {d2 - d1:>8.2f}")


if __name__ == "__main__":
    main()
