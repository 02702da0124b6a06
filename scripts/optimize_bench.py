"""`toporec optimize` against GTSAM's Levenberg–Marquardt on public g2o pose graphs.

For each graph: GTSAM reads it (`readG2o`), holds the first vertex with a tight prior, runs
`LevenbergMarquardtOptimizer` at its default parameters and writes the result (`writeG2o`), all
in one process; `toporec optimize GRAPH -o OUT` does the same as a whole process. Both on one
thread. Each result is read back with `readG2o` and scored by GTSAM's `graph.error` over the
file's own edges, so the two costs are the same function. Times are wall seconds, median of
`--runs`.

Each solver starts twice: from the file's own vertices, and from its own initialization for
graphs far from their solution: GTSAM's `InitializePose3` (chordal relaxation) in space and
`lago.initialize` in the plane, toporec's `--start chordal`.

    python3 scripts/optimize_bench.py --toporec target/release/toporec \
        ../shared/data/posegraphs/parking-garage.g2o ../shared/data/posegraphs/w20000.g2o

GTSAM (`pip install gtsam`) is a benchmark tool here, never a dependency of toporec.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

GTSAM_RUN = r"""
import sys, gtsam, numpy as np
path, out, is3d, start = sys.argv[1], sys.argv[2], sys.argv[3] == "3", sys.argv[4]
graph, initial = gtsam.readG2o(path, is3d)
if is3d:
    prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6] * 3 + [1e-4] * 3))
    graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), prior))
else:
    prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), prior))
if start == "chordal":
    initial = gtsam.InitializePose3.initialize(graph) if is3d else gtsam.lago.initialize(graph)
optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
result = optimizer.optimize()
gtsam.writeG2o(graph, result, out)
print(optimizer.iterations())
"""


def is_3d(path):
    with open(path) as f:
        for line in f:
            if line.startswith("VERTEX_SE3"):
                return True
            if line.startswith("VERTEX_SE2"):
                return False
    raise SystemExit(f"{path}: no VERTEX_SE2 or VERTEX_SE3:QUAT line")


def error_of(original, result, three):
    """GTSAM's graph.error of `result`'s poses over `original`'s edges."""
    import gtsam

    graph, _ = gtsam.readG2o(original, three)
    _, values = gtsam.readG2o(result, three)
    return graph.error(values)


def timed(argv, env):
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stderr}")
    return seconds, done.stdout


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graphs", nargs="+")
    parser.add_argument("--toporec", default="target/release/toporec")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               RAYON_NUM_THREADS="1", TBB_NUM_THREADS="1")
    print("| graph | start | solver | cost (GTSAM `graph.error`) | iterations | seconds (median of "
          f"{args.runs}) |")
    print("|---|---|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as scratch:
        for graph in args.graphs:
            three = is_3d(graph)
            name = os.path.basename(graph)
            rows = []
            for start in ["file", "chordal"]:
                out = os.path.join(scratch, "gtsam.g2o")
                runs = [timed([sys.executable, "-c", GTSAM_RUN, graph, out, "3" if three else "2", start], env)
                        for _ in range(args.runs)]
                initializer = "InitializePose3" if three else "LAGO"
                rows.append((start, "GTSAM LM" if start == "file" else f"GTSAM {initializer} + LM",
                             error_of(graph, out, three), runs[0][1].strip(), statistics.median(s for s, _ in runs)))
                out = os.path.join(scratch, "toporec.g2o")
                runs = [timed([args.toporec, "optimize", graph, "-o", out, "--start", start], env)
                        for _ in range(args.runs)]
                said = runs[0][1]
                iterations = said.split(" in ")[1].split(" iterations")[0] if " in " in said else "?"
                rows.append((start, f"toporec optimize --start {start}", error_of(graph, out, three), iterations,
                             statistics.median(s for s, _ in runs)))
            for start, solver, cost, iterations, seconds in rows:
                print(f"| {name} | {start} | {solver} | {cost:.6f} | {iterations} | {seconds:.2f} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
