"""Spark local[2] against `toporec run --threads 2` on the same simulated drive, in scans/s.

    python3 python/bench/bench_spark.py [--scans 1000] [--sessions 2] [--driver-java-options OPTS]

Simulates the drive (`toporec simulate`, NCLT format), freezes one codebook (`toporec fit
--pipeline --sample 0.1`) in two index folders, then times `toporec run --threads 2` into one
and `toporec.spark.index_files` on a `local[2]` session into the other (the session is started
before the clock, as a cluster's would be). Prints a Markdown table. Needs the release binary
(`cargo build --release`). `--driver-java-options` goes to the local JVM (for example
`-XX:TieredStopAtLevel=1`: no C2 compilation, which on two cores competes with the tasks).
"""

import argparse
import pathlib
import shutil
import subprocess
import tempfile
import time

import toporec

REPO = pathlib.Path(__file__).resolve().parents[2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", type=int, default=1000, help="scans per session")
    ap.add_argument("--sessions", type=int, default=2)
    ap.add_argument("--driver-java-options", default="", help="options of the local Spark JVM")
    args = ap.parse_args()
    binary = REPO / "target" / "release" / "toporec"
    work = pathlib.Path(tempfile.mkdtemp(prefix="toporec-spark-bench-"))
    try:
        drive = work / "drive"
        subprocess.run(
            [binary, "simulate", "-o", drive, "--format", "nclt", "--sessions", str(args.sessions), "--scans", str(args.scans)],
            check=True,
            capture_output=True,
        )
        pipeline = work / "drive.toml"
        text = (REPO / "pipelines" / "sample.toml").read_text()
        text = text.replace('"../out/sample"', '"index"').replace('"../samples/town/velodyne_data"', f'"{drive / "velodyne_data"}"')
        pipeline.write_text(text)
        by_run, by_spark = work / "run", work / "spark"
        for index in (by_run, by_spark):
            toporec.fit(pipeline, sample=0.1, index=index)
        t = time.perf_counter()
        subprocess.run([binary, "run", pipeline, "--index", by_run, "--threads", "2", "--no-progress"], check=True, capture_output=True)
        run_secs = time.perf_counter() - t

        from pyspark.sql import SparkSession

        from toporec.spark import index_files

        builder = SparkSession.builder.master("local[2]").config("spark.ui.enabled", "false")
        if args.driver_java_options:
            builder = builder.config("spark.driver.extraJavaOptions", args.driver_java_options)
        spark = builder.getOrCreate()
        spark.sparkContext.setLogLevel("ERROR")
        t = time.perf_counter()
        result = index_files(spark, [drive / "velodyne_data"], by_spark)
        spark_secs = time.perf_counter() - t
        spark.stop()
        n = result["scans"]
        print("| engine | scans | seconds | scans/s |\n|---|---:|---:|---:|")
        print(f"| toporec run --threads 2 | {n} | {run_secs:.1f} | {n / run_secs:.1f} |")
        print(f"| Spark local[2] | {n} | {spark_secs:.1f} | {n / spark_secs:.1f} |")
        print(f"overhead: {100 * (spark_secs / run_secs - 1):.1f} %")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
