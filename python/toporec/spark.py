"""Indexing with Apache Spark: the same index ``toporec run`` writes, computed by a cluster.

    from pyspark.sql import SparkSession
    from toporec.spark import index_files

    spark = SparkSession.builder.master("local[2]").getOrCreate()
    index_files(spark, ["samples/town/velodyne_data"], "out/spark", pipeline="pipelines/sample.toml")

1. The codebook: the index's frozen one when it has one, else fitted on the driver on a
   hash sample of the pipeline's scans (``toporec fit --pipeline``) and frozen in the index.
   Executors read it from the index folder, which they must see (a shared file system).
2. Scan files are read with ``spark.read.format("binaryFile")`` (NCLT ``velodyne_sync/*.bin``,
   KITTI ``velodyne/*.bin``); each keeps its position in the sorted file list as its ``seq``.
3. ``mapInArrow`` calls :func:`toporec.describe_batch` on each Arrow batch (a scan that fails
   is an ``error`` row, never a failed task) and returns the rows of the three tables.
4. They are written with ``write.partitionBy("session").parquet(...)`` into a staging folder
   inside the index (``.spark-<id>``), in toporec's layout, then merged into the index in one
   commit under its lock: manifest, checksums and counts, so ``toporec query``, ``eval`` and
   ``verify`` accept it. A job that dies before the merge leaves the index as it was.

Spark has no unsigned integers: ``seq``, ``raw_points``, ``kept_points``, ``message_index``
are written as int64, ``dim`` and ``dim_used`` as int8 (Spark's byte), and descriptors as a
list of float32; toporec's readers cast them back to its own types.
"""

from __future__ import annotations

import os
import shutil
import uuid
from typing import Any, Dict, List, Optional, Sequence, Union

import pyarrow as pa

import toporec

PathLike = Union[str, "os.PathLike[str]"]

_SCAN_COLUMNS = [
    ("scan_id", pa.string(), "string"),
    ("fingerprint", pa.string(), "string"),
    ("settings_hash", pa.string(), "string"),
    ("seq", pa.int64(), "bigint"),
    ("source_path", pa.string(), "string"),
    ("message_index", pa.int64(), "bigint"),
    ("utime", pa.int64(), "bigint"),
    ("pose_x", pa.float64(), "double"),
    ("pose_y", pa.float64(), "double"),
    ("pose_z", pa.float64(), "double"),
    ("pose_yaw", pa.float64(), "double"),
    ("raw_points", pa.int64(), "bigint"),
    ("kept_points", pa.int64(), "bigint"),
    ("status", pa.string(), "string"),
    ("error", pa.string(), "string"),
]
_DIAGRAM_COLUMNS = [("dim", pa.int8(), "tinyint"), ("birth", pa.float64(), "double"), ("death", pa.float64(), "double")]
_DESCRIPTOR_COLUMNS = [
    ("method", pa.string(), "string"),
    ("dim_used", pa.int8(), "tinyint"),
    ("descriptor", pa.list_(pa.float32()), "array<float>"),
    ("codebook_id", pa.string(), "string"),
]
# One row type for all three tables (mapInArrow returns one schema): `kind` says which.
_UNION = [("kind", pa.string(), "string"), ("session", pa.string(), "string")] + _SCAN_COLUMNS + _DIAGRAM_COLUMNS + _DESCRIPTOR_COLUMNS
UNION_SCHEMA = pa.schema([pa.field(n, t) for n, t, _ in _UNION])
UNION_DDL = ", ".join(f"{n} {d}" for n, _, d in _UNION)

SCAN_FIELDS = [n for n, _, _ in _SCAN_COLUMNS]
DIAGRAM_FIELDS = ["scan_id", "dim", "birth", "death"]
DESCRIPTOR_FIELDS = ["scan_id", "utime", "pose_x", "pose_y", "pose_z", "dim_used", "descriptor", "codebook_id"]


def local_path(path: str) -> str:
    """A Spark file URI (``file:/a/b``, ``file:///a/b``) as a local path; others unchanged."""
    if path.startswith("file://"):
        return path[len("file://"):]
    if path.startswith("file:"):
        return path[len("file:"):]
    return path


def _union(kind: str, table: pa.Table, method: Optional[str] = None) -> pa.Table:
    n = table.num_rows
    columns = []
    for name, typ, _ in _UNION:
        if name == "kind":
            columns.append(pa.array([kind] * n, pa.string()))
        elif name == "method" and method is not None:
            columns.append(pa.array([method] * n, pa.string()))
        elif name in table.column_names:
            column = table.column(name)
            if pa.types.is_fixed_size_list(column.type):
                column = column.cast(pa.list_(pa.float32()))
            columns.append(column.cast(typ))
        else:
            columns.append(pa.nulls(n, typ))
    return pa.Table.from_arrays(columns, schema=UNION_SCHEMA)


def describe_partition(batches, index: str):
    """The ``mapInArrow`` function: Arrow batches of ``binaryFile`` rows (with ``seq``) in,
    union rows of the three tables out."""
    for batch in batches:
        if batch.num_rows == 0:
            continue
        paths = [local_path(p) for p in batch.column("path").to_pylist()]
        scans = pa.table({"path": paths, "content": batch.column("content"), "seq": batch.column("seq").cast(pa.uint64())})
        out = toporec.describe_batch(scans, index)
        parts = [_union("scan", out["scans"]), _union("pair", out["diagrams"])]
        parts += [_union("descriptor", t, m) for m, t in out["descriptors"].items()]
        yield from pa.concat_tables(parts).to_batches()


def index_files(
    spark: Any,
    inputs: Sequence[PathLike],
    index: PathLike,
    *,
    pipeline: Optional[PathLike] = None,
    sample: float = 0.1,
    partitions: Optional[int] = None,
    glob: str = "*.bin",
) -> Dict[str, Any]:
    """Indexes the scan files under ``inputs`` into ``index`` with Spark (see the module doc).

    Args:
        spark: a SparkSession (any master: ``local[2]``, a standalone, YARN or Kubernetes cluster).
        inputs: folders or files, as ``spark.read.format("binaryFile").load`` takes them
            (``file:/…``, ``s3a://…``, …); folders are read recursively for ``glob``.
        index: the index folder (on a file system every executor sees).
        pipeline: the pipeline file whose settings the index takes, needed when the index has
            no codebook yet (then fitted on ``sample`` of its scans on the driver).
        sample: the fraction of the pipeline's scans the codebook is fitted on.
        partitions: repartition the files into this many tasks (default: Spark's split).
        glob: the scan files' name pattern.

    Returns:
        ``{"scans": n, "ok": n, "errors": n, "index": path}``.
    """
    from pyspark import StorageLevel
    from pyspark.sql import Window
    from pyspark.sql import functions as F

    index = os.path.abspath(os.fspath(index))
    if not _has_codebook(index):
        if pipeline is None:
            raise ValueError(f"{index}: no codebook yet; give `pipeline` to fit one on a sample of its scans")
        toporec.fit(pipeline, sample=sample, index=index)
    files = (
        spark.read.format("binaryFile")
        .option("pathGlobFilter", glob)
        .option("recursiveFileLookup", "true")
        .load([os.fspath(p) for p in inputs])
    )
    # Each file's place in the sorted list: the `seq` toporec run gives it.
    order = files.select("path").withColumn("seq", F.row_number().over(Window.orderBy("path")) - F.lit(1))
    scans = files.select("path", "content").join(order, "path")
    if partitions:
        scans = scans.repartition(partitions)
    rows = scans.mapInArrow(lambda batches: describe_partition(batches, index), UNION_DDL)
    rows = rows.persist(StorageLevel.DISK_ONLY)
    staging = os.path.join(index, f".spark-{uuid.uuid4().hex[:12]}")
    try:
        kind = F.col("kind")
        write = lambda df, path: df.write.mode("overwrite").option("compression", "zstd").partitionBy("session").parquet(path)  # noqa: E731
        write(rows.filter(kind == "scan").select(*SCAN_FIELDS, "session"), os.path.join(staging, "scans"))
        write(rows.filter(kind == "pair").select(*DIAGRAM_FIELDS, "session"), os.path.join(staging, "diagrams"))
        methods = [m for m, _ in toporec._toporec.BatchDescriber(index).methods()]
        for method in methods:
            chosen = rows.filter((kind == "descriptor") & (F.col("method") == method))
            write(chosen.select(*DESCRIPTOR_FIELDS, "session"), os.path.join(staging, "descriptors", f"method={method}"))
        counts = {r["status"]: r["count"] for r in rows.filter(kind == "scan").groupBy("status").count().collect()}
        toporec._toporec.merge_written(index, staging)
    finally:
        rows.unpersist()
        shutil.rmtree(staging, ignore_errors=True)
    return {
        "index": index,
        "scans": sum(counts.values()),
        "ok": counts.get("ok", 0),
        "skipped": counts.get("skipped", 0),
        "errors": counts.get("error", 0),
    }


def _has_codebook(index: str) -> bool:
    import json

    try:
        with open(os.path.join(index, "manifest.json")) as f:
            return json.load(f).get("codebook") is not None
    except FileNotFoundError:
        return False


def main(argv: Optional[List[str]] = None) -> None:
    """``spark-submit python/toporec/spark.py --index DIR [--pipeline FILE] INPUT ...``"""
    import argparse

    from pyspark.sql import SparkSession

    ap = argparse.ArgumentParser(description="Index LiDAR scan files with Spark into a toporec index.")
    ap.add_argument("inputs", nargs="+", help="folders or files (file:/..., s3a://..., hdfs://...)")
    ap.add_argument("--index", required=True, help="the index folder (shared by every executor)")
    ap.add_argument("--pipeline", help="the pipeline file (settings; needed when the index has no codebook)")
    ap.add_argument("--sample", type=float, default=0.1, help="fraction of scans the codebook is fitted on")
    ap.add_argument("--partitions", type=int, help="tasks to split the files into")
    ap.add_argument("--master", help="Spark master (default: spark-submit's)")
    args = ap.parse_args(argv)
    builder = SparkSession.builder.appName("toporec-index")
    if args.master:
        builder = builder.master(args.master)
    spark = builder.getOrCreate()
    result = index_files(spark, args.inputs, args.index, pipeline=args.pipeline, sample=args.sample, partitions=args.partitions)
    print(result)
    spark.stop()


if __name__ == "__main__":
    main()
