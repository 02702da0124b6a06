"""toporec.alpha_persistence against GUDHI's AlphaComplex in one Python process.

    python3 python/bench/bench_alpha.py [--repeat 5]

Clouds: the 4096-point fixtures (uniform cube, synthetic LiDAR scene) and 30,000 uniform
points. GUDHI: ``AlphaComplex(points=p, precision=...).create_simplex_tree().persistence()``,
in its default ``safe`` precision and in ``exact`` (the precision toporec's diagrams equal).
The boundary cost is the call's wall time minus the engine's own time (measured inside the
Rust call): converting the numpy array in and building the result arrays.
Prints a Markdown table (median wall time of --repeat runs).
"""

import argparse
import pathlib
import platform
import statistics
import time

import gudhi
import numpy as np

import toporec
from toporec import _toporec

REPO = pathlib.Path(__file__).resolve().parents[2]


def median_seconds(f, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    fixtures = REPO / "tests" / "fixtures" / "clouds"
    clouds = {
        "uniform_cube_4096": np.loadtxt(fixtures / "uniform_cube_4096.csv", delimiter=",", skiprows=1),
        "lidar_like_4096": np.loadtxt(fixtures / "lidar_like_4096.csv", delimiter=",", skiprows=1),
        "uniform_30000": np.random.default_rng(0).random((30000, 3)) * 40.0,
    }
    print(f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}, gudhi {gudhi.__version__}, toporec {toporec.__version__}")
    print("| cloud | toporec ms | boundary % | GUDHI safe ms | GUDHI exact ms | × safe | × exact |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, p in clouds.items():
        ours = median_seconds(lambda: toporec.alpha_persistence(p), args.repeat)
        boundary = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            _, engine = _toporec.alpha_persistence_timed(np.ascontiguousarray(p, dtype=np.float64), [0, 1, 2], True)
            wall = time.perf_counter() - t
            boundary.append((wall - engine) / wall)
        safe = median_seconds(lambda: gudhi.AlphaComplex(points=p).create_simplex_tree().persistence(), args.repeat)
        exact = median_seconds(
            lambda: gudhi.AlphaComplex(points=p, precision="exact").create_simplex_tree().persistence(), args.repeat
        )
        print(
            f"| {name} | {ours * 1e3:.1f} | {100 * statistics.median(boundary):.2f} | {safe * 1e3:.1f} | "
            f"{exact * 1e3:.1f} | {safe / ours:.1f} | {exact / ours:.1f} |"
        )


if __name__ == "__main__":
    main()
