"""A simulated SE(3) pose graph of N scans with loops, in g2o's format, for `toporec optimize`'s
size benchmark.

A robot drives a random Manhattan walk over a town's street grid (blocks of 40 m, a scan every
2 m), with odometry that drifts (1 % long, 0.0002 rad a metre to the left, and 1 cm / 1 mrad of
noise a step). Whenever it passes within 1 m of a place it scanned more than 100 scans before, a
loop is added with the true relative pose plus ICP-sized noise (2 cm, 2 mrad). Vertices start at
the odometry (`--initial truth`: at the truth); the first is held.

    python3 scripts/posegraph_synthetic.py --scans 100000 -o big.g2o
    /usr/bin/time -v target/release/toporec optimize big.g2o -o big.optimized.g2o --robust
"""

import argparse
import math
import random


def quaternion(yaw):
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def upper_triangle(diagonal):
    """g2o's 21 upper-triangular entries of a diagonal information matrix."""
    return " ".join(str(diagonal[i] if i == j else 0.0) for i in range(6) for j in range(i, 6))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=100000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("-o", "--out", required=True)
    parser.add_argument("--initial", choices=["odometry", "truth"], default="odometry",
                        help="where the vertices start: the chained odometry, or the truth (to time a "
                        "graph's size apart from how far its start is from the solution)")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    step, block = 2.0, 40.0
    truth = []
    x, y, heading = 0.0, 0.0, 0
    for k in range(args.scans):
        truth.append((x, y, heading * math.pi / 2))
        # At a crossing, go on, left or right.
        if abs(x / block - round(x / block)) < 1e-9 and abs(y / block - round(y / block)) < 1e-9 and k:
            heading = (heading + rng.choice([0, 0, 1, -1])) % 4
        dx, dy = [(step, 0), (0, step), (-step, 0), (0, -step)][heading]
        x, y = round(x + dx, 6), round(y + dy, 6)
    info_odometry = upper_triangle([2500.0] * 3 + [1e4] * 3)
    info_loop = upper_triangle([2500.0] * 3 + [2.5e5] * 3)
    ox, oy, oyaw = truth[0]
    vertices = [(ox, oy, oyaw)]
    edges = []
    for k in range(1, len(truth)):
        (ax, ay, ayaw), (bx, by, byaw) = truth[k - 1], truth[k]
        c, s = math.cos(ayaw), math.sin(ayaw)
        fx, fy = c * (bx - ax) + s * (by - ay), -s * (bx - ax) + c * (by - ay)
        dyaw = byaw - ayaw
        d = math.hypot(fx, fy)
        fx, fy = fx * 1.01 + rng.gauss(0, 0.01), fy * 1.01 + rng.gauss(0, 0.01)
        dyaw += 0.0002 * d + rng.gauss(0, 0.001)
        edges.append((k - 1, k, fx, fy, dyaw, info_odometry))
        c, s = math.cos(oyaw), math.sin(oyaw)
        ox, oy, oyaw = ox + c * fx - s * fy, oy + s * fx + c * fy, oyaw + dyaw
        vertices.append((ox, oy, oyaw))
    seen = {}
    loops = 0
    for k, (x, y, yaw) in enumerate(truth):
        key = (round(x), round(y))
        earlier = seen.get(key)
        if earlier is not None and k - earlier > 100:
            ax, ay, ayaw = truth[earlier]
            c, s = math.cos(ayaw), math.sin(ayaw)
            fx, fy = c * (x - ax) + s * (y - ay), -s * (x - ax) + c * (y - ay)
            edges.append((earlier, k, fx + rng.gauss(0, 0.02), fy + rng.gauss(0, 0.02),
                          yaw - ayaw + rng.gauss(0, 0.002), info_loop))
            loops += 1
        seen[key] = k
    if args.initial == "truth":
        vertices = truth
    with open(args.out, "w") as f:
        for k, (x, y, yaw) in enumerate(vertices):
            qx, qy, qz, qw = quaternion(yaw)
            f.write(f"VERTEX_SE3:QUAT {k} {x} {y} 0 {qx} {qy} {qz} {qw}\n")
        for a, b, fx, fy, dyaw, info in edges:
            qx, qy, qz, qw = quaternion(dyaw)
            f.write(f"EDGE_SE3:QUAT {a} {b} {fx} {fy} 0 {qx} {qy} {qz} {qw} {info}\n")
        f.write("FIX 0\n")
    print(f"{args.out}: {len(vertices)} vertices, {len(edges) - loops} odometry edges, {loops} loops")


if __name__ == "__main__":
    main()
