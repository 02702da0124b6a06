"""Indexing with Apache Spark: the same index ``toporec run`` writes, computed by a cluster.

    from pyspark.sql import SparkSession
    from toporec.spark import index_files

    spark = SparkSession.builder.master("local[2]").getOrCreate()
    index_files(spark, ["samples/town/velodyne_data"], "out/spark", pipeline="pipelines/sample.toml")

1. The codebook: the index's frozen one when it has one, else fitted on the driver on a
   hash sample of the pipeline's scans (``toporec fit --pipeline``) and frozen in the index.
   Executors read it from the index folder, which they must see (a shared file system).
2. Scan files (NCLT ``velodyne_sync/*.bin``, KITTI ``velodyne/*.bin``) are listed on the
   driver, which reads no content: local folders (``file:``, mounted on every executor) by
   walking them, as ``spark.read.format("binaryFile")`` with ``recursiveFileLookup`` would
   list them; others (``s3a://``, ``hdfs://``, globs; or ``read="spark"``) by that
   ``binaryFile`` read's file index. Local files are read by the tasks themselves, a run of
   ``scans_per_task`` files each: their bytes do not pass through the JVM. Files elsewhere
   come as the ``binaryFile`` rows' content. Message logs (MCAP files, ROS 1 bags, rosbag2
   folders and ``.db3`` files) are listed the same way and split by message ranges
   (``messages_per_task`` scans a task, counted by a first pass on the executors); a task
   reads its range from the log's path, decoding only its own messages. Each scan keeps its
   position in the sorted file list (a log's scans in message order) as its ``seq``.
3. ``mapInArrow`` calls :func:`toporec.describe_batch` on each Arrow batch (a scan that fails
   is an ``error`` row, never a failed task). The diagrams and each method's descriptors are
   written by the task itself, by toporec's own Parquet writer, into a staging folder inside
   the index (``.spark-<id>``): one file per table and session, under a name fixed by the
   batch's files, so that a retried or recomputed task replaces its own files. The task
   returns one row per scan: its ``scans`` columns.
4. Those rows are written with ``write.partitionBy("session").parquet(...)`` as the ``scans``
   table of the staging folder: the job's only Spark write, in the job that describes the
   scans. Passing the diagrams (thousands of rows per scan, nearly all of a job's rows)
   through Spark's row-wise writer would cost more than describing the scans; the
   descriptors through it, a second job over kept rows (docs/distributed.md gives the
   figures).
5. The staging folder is merged into the index in one commit under its lock: manifest,
   checksums and counts, so ``toporec query``, ``eval`` and ``verify`` accept it. A job that
   dies before the merge leaves the index as it was.

Spark has no unsigned integers: ``seq``, ``raw_points``, ``kept_points`` and ``message_index``
are written as int64; toporec's readers cast them back to its own types.
"""

from __future__ import annotations

import os
import shutil
import time
import uuid
from typing import Any, Dict, List, Optional, Sequence, Union

import pyarrow as pa

import toporec

PathLike = Union[str, "os.PathLike[str]"]

def _spark_column(field: pa.Field) -> tuple:
    """A column of toporec's ``scans`` table as Spark holds it: its name, the Arrow type of the
    rows handed to Spark, and its Spark SQL type (Spark has no unsigned integers: they travel as
    int64, and toporec's readers cast them back)."""
    t = field.type
    if pa.types.is_string(t):
        return field.name, pa.string(), "string"
    if pa.types.is_integer(t):
        return field.name, pa.int64(), "bigint"
    if pa.types.is_floating(t):
        return field.name, pa.float64(), "double"
    raise TypeError(f"scans.{field.name}: no Spark column for {t}")


# The `scans` table as toporec declares it (`schemas/scans.json`), column by column.
_SCAN_COLUMNS = [
    _spark_column(f) for f in pa.RecordBatchReader.from_stream(toporec._toporec.table_schema("scans")).schema
]


def scan_row_schema() -> List[Any]:
    """The columns of the rows ``mapInArrow`` returns: one row per scan, with its session and
    its ``scans`` columns. The diagrams and descriptors do not pass through Spark: each task
    writes them (see the module doc)."""
    return [("session", pa.string(), "string")] + list(_SCAN_COLUMNS)


def local_path(path: str) -> str:
    """A Spark file URI (``file:/a/b``, ``file:///a/b``) as a local path; others unchanged."""
    if path.startswith("file://"):
        return path[len("file://"):]
    if path.startswith("file:"):
        return path[len("file:"):]
    return path


def scan_rows(out: Dict[str, Any]) -> pa.Table:
    """The per-scan rows (:func:`scan_row_schema`) of one :func:`toporec.describe_batch` result."""
    scans = out["scans"]
    schema = pa.schema([pa.field(n, t) for n, t, _ in scan_row_schema()])
    data: Dict[str, Any] = {"session": scans.column("session")}
    for name, typ, _ in _SCAN_COLUMNS:
        data[name] = scans.column(name).cast(typ)
    return pa.Table.from_pydict(data, schema=schema)


def _task_threads() -> None:
    """A Spark task has ``spark.task.cpus`` cores: the engine's thread pool, made at its first
    use in this worker process, takes as many (unless ``RAYON_NUM_THREADS`` says otherwise)."""
    from pyspark import TaskContext

    context = TaskContext.get()
    os.environ.setdefault("RAYON_NUM_THREADS", str(context.cpus() if context is not None else 1))


def describe_partition(batches, index: str, seqs: Dict[str, int], staging: str):
    """The ``mapInArrow`` function: Arrow batches of ``binaryFile`` rows in, one row per scan
    (:func:`scan_row_schema`) out; each batch's diagrams and descriptors are written under
    ``staging``.
    ``seqs``: each file's place in the job (the ``seq`` ``toporec run`` gives it)."""
    _task_threads()
    for batch in batches:
        if batch.num_rows == 0:
            continue
        uris = batch.column("path").to_pylist()
        scans = pa.table({
            "path": [local_path(p) for p in uris],
            "content": batch.column("content"),
            "seq": pa.array([seqs[_uri(p)] for p in uris], pa.uint64()),
        })
        out = toporec.describe_batch(scans, index, write_to=staging)
        yield from scan_rows(out).to_batches()


def describe_paths(batches, index: str, chunks: Any, staging: str):
    """The ``mapInArrow`` function of scan files every executor mounts: rows of ``id`` (a run
    of files in ``chunks``, a broadcast list of runs of ``(path, seq)``) in, one row per scan
    out (as :func:`describe_partition`). The engine reads the files; one that cannot be read
    is an ``error`` row naming it."""
    _task_threads()
    for batch in batches:
        for i in batch.column("id").to_pylist():
            run = chunks.value[i]
            scans = pa.table({
                "path": [local_path(p) for p, _ in run],
                "seq": pa.array([q for _, q in run], pa.uint64()),
            })
            out = toporec.describe_batch(scans, index, write_to=staging)
            yield from scan_rows(out).to_batches()


def _uri(uri: str) -> str:
    """One spelling of a file URI: ``file:///a/b`` (a listing's) as ``file:/a/b`` (a row's)."""
    scheme, sep, rest = uri.partition(":///")
    return f"{scheme}:/{rest}" if sep and "/" not in scheme else uri


def _is_local(uri: str) -> bool:
    """Whether a listed file is on the local file system (``file:``), which the tasks read."""
    return uri.startswith("file:") or "://" not in uri


def describe_ranges(batches, index: str, staging: str):
    """The ``mapInArrow`` function of message logs: rows of message ranges (``path``,
    ``first_message``, ``message_count``, ``seq``) in, one row per scan out (as
    :func:`describe_partition`)."""
    _task_threads()
    for batch in batches:
        if batch.num_rows == 0:
            continue
        ranges = pa.table({
            "path": [local_path(p) for p in batch.column("path").to_pylist()],
            "format": pa.array(["mcap"] * batch.num_rows, pa.string()),
            "first_message": batch.column("first_message").cast(pa.uint64()),
            "message_count": batch.column("message_count").cast(pa.uint64()),
            "seq": batch.column("seq").cast(pa.uint64()),
        })
        out = toporec.describe_batch(ranges, index, write_to=staging)
        yield from scan_rows(out).to_batches()


def _count_scans(batches):
    """The ``mapInArrow`` function that counts each log's scans (and names its topic)."""
    for batch in batches:
        paths = batch.column("path").to_pylist()
        counted = [toporec._toporec.mcap_scan_count(local_path(p)) for p in paths]
        yield pa.RecordBatch.from_pydict({
            "path": paths,
            "topic": [t for t, _ in counted],
            "scans": pa.array([n for _, n in counted], pa.int64()),
        })


def _listing(spark: Any, inputs: Sequence[str], glob: str) -> Any:
    """The files under ``inputs`` matching ``glob`` as a ``binaryFile`` DataFrame."""
    reader = spark.read.format("binaryFile").option("pathGlobFilter", glob).option("recursiveFileLookup", "true")
    return reader.load(list(inputs))


def _local_inputs(spark: Any, inputs: Sequence[str]) -> bool:
    """Whether every input is a plain folder or file on the local file system: a ``file:``
    URI, or a path without a scheme where Hadoop's default file system is the local one
    (on a cluster whose default is HDFS, ``/data`` is an HDFS folder), and no glob."""
    default_fs = spark.sparkContext._jsc.hadoopConfiguration().get("fs.defaultFS") or "file:///"

    def local(p: str) -> bool:
        if any(c in p for c in "*?[{"):
            return False
        if p.startswith("file:"):
            return True
        return "://" not in p and not p.split("/", 1)[0].endswith(":") and default_fs.startswith("file:")

    return all(local(p) for p in inputs)


def _hidden(name: str) -> bool:
    """A name Spark's file listing skips (``_SUCCESS``, ``.staging``, ``._COPYING_`` files)."""
    return name.startswith(("_", ".")) or name.endswith("._COPYING_")


def _local_files(inputs: Sequence[str], glob: str) -> List[str]:
    """The files under local ``inputs`` whose names match ``glob``, as ``file:`` URIs, sorted:
    what a ``binaryFile`` read with ``recursiveFileLookup`` lists (hidden names skipped below
    an input), without the JVM's file index (which costs a fresh driver about a second)."""
    import fnmatch

    found = []
    for given in inputs:
        root = os.path.abspath(local_path(given))
        if os.path.isfile(root):
            candidates = [root]
        elif os.path.isdir(root):
            candidates = []
            for folder, dirs, names in os.walk(root, followlinks=True):
                dirs[:] = [d for d in dirs if not _hidden(d)]
                candidates += [os.path.join(folder, n) for n in names if not _hidden(n)]
        else:
            raise FileNotFoundError(f"{given}: no such file or folder")
        found += [f"file:{c}" for c in candidates if fnmatch.fnmatchcase(os.path.basename(c), glob)]
    return sorted(set(found))


LOG_GLOBS = ("*.mcap", "*.bag", "*.db3", "metadata.yaml")
"""The message logs :func:`index_files` lists by default: MCAP files, ROS 1 bags, lone rosbag2
``.db3`` files, and rosbag2 folders (found by their ``metadata.yaml``)."""


def _logs(files: Sequence[str]) -> List[str]:
    """The logs among listed files, sorted: each folder holding a ``metadata.yaml`` (a rosbag2
    folder, read whole, as ``toporec run`` reads it), and every other file not inside one."""
    folders = sorted({f.rsplit("/", 1)[0] for f in files if f.rsplit("/", 1)[-1] == "metadata.yaml"})
    inside = tuple(d + "/" for d in folders)
    return sorted(set(folders) | {f for f in files if not f.startswith(inside) and f.rsplit("/", 1)[-1] != "metadata.yaml"})


def index_files(
    spark: Any,
    inputs: Sequence[PathLike],
    index: PathLike,
    *,
    pipeline: Optional[PathLike] = None,
    sample: float = 0.1,
    scans_per_task: Optional[int] = None,
    read: str = "auto",
    glob: str = "*.bin",
    log_globs: Sequence[str] = LOG_GLOBS,
    messages_per_task: int = 64,
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
        scans_per_task: scan files per task (default: about a quarter of a core's share,
            at most 256).
        read: who reads the scan files' bytes: ``"auto"``, the tasks themselves when every
            file is on the local file system (``file:``, mounted on every executor), Spark's
            ``binaryFile`` rows otherwise; ``"spark"``, always Spark.
        glob: the scan files' name pattern (NCLT ``velodyne_sync`` and KITTI ``velodyne``
            files, one scan each).
        log_globs: the message logs' name patterns (empty: no logs): MCAP files, ROS 1 bags and
            lone rosbag2 ``.db3`` files; a folder holding a ``metadata.yaml`` is one rosbag2
            log (its storage files are not listed apart). Each log is split into tasks of
            ``messages_per_task`` scans; a task reads its log from the path (on a file system
            every executor mounts), decoding only its own messages.
        messages_per_task: scans per log task.

    Returns:
        ``{"scans": n, "ok": n, "skipped": n, "errors": n, "index": path}``.
    """
    if messages_per_task < 1:
        raise ValueError(f"messages_per_task: must be >= 1; found {messages_per_task}")
    if read not in ("auto", "spark"):
        raise ValueError(f"read: expected auto or spark; found {read!r}")
    if scans_per_task is not None and scans_per_task < 1:
        raise ValueError(f"scans_per_task: must be >= 1; found {scans_per_task}")
    index = os.path.abspath(os.fspath(index))
    if not _has_codebook(index):
        if pipeline is None:
            raise ValueError(f"{index}: no codebook yet; give `pipeline` to fit one on a sample of its scans")
        toporec.fit(pipeline, sample=sample, index=index)
    inputs = [os.fspath(p) for p in inputs]
    # The listing is the driver's, no job: local folders are walked directly, others listed by
    # the file index Spark builds for a `binaryFile` read.
    if read == "auto" and _local_inputs(spark, inputs):
        scan_files = _local_files(inputs, glob)
        logs_listed = _logs([f for g in log_globs for f in _local_files(inputs, g)])
    else:
        files = _listing(spark, inputs, glob)
        scan_files = sorted(_uri(p) for p in files.inputFiles())
        logs_listed = _logs([_uri(p) for g in log_globs for p in _listing(spark, inputs, g).inputFiles()])
    # Scan counts of the logs (one pass over each, on the executors).
    counts: Dict[str, int] = {}
    if logs_listed:
        paths_df = spark.createDataFrame([(p,) for p in logs_listed], "path string").repartition(len(logs_listed))
        counted = paths_df.mapInArrow(_count_scans, "path string, topic string, scans bigint").collect()
        counts = {r["path"]: r["scans"] for r in counted}
    # Each scan's place in the sorted file list (an MCAP file's scans in message order) is
    # the `seq` toporec run gives it.
    seqs, position = {}, 0
    for p in sorted(scan_files + list(counts)):
        seqs[p] = position
        position += counts.get(p, 1)
    ddl = ", ".join(f"{n} {d}" for n, _, d in scan_row_schema())
    staging = os.path.join(index, f".spark-{uuid.uuid4().hex[:12]}")
    slots = max(1, spark.sparkContext.defaultParallelism)
    # Tasks of about a quarter of a core's share (at most 256 scans) keep the cores busy to
    # the end; each task costs ~0.1 s of a core beyond its scans.
    size = scans_per_task or max(1, min(256, -(-len(scan_files) // (4 * slots))))
    conf: Dict[str, str] = {}
    if read == "auto" and all(_is_local(p) for p in scan_files):
        # Files every executor mounts are read by the task itself: their bytes do not pass
        # through the JVM and its Arrow hand-over (a tenth of the describing's time on two
        # cores). Task i takes the i-th run of `size` files (sent once to each executor).
        files_seqs = [(p, seqs[p]) for p in scan_files]
        runs = [files_seqs[i:i + size] for i in range(0, len(files_seqs), size)]
        chunks = spark.sparkContext.broadcast(runs)
        ids = spark.range(len(runs), numPartitions=max(1, len(runs)))
        rows = ids.mapInArrow(lambda batches: describe_paths(batches, index, chunks, staging), ddl)
    else:
        # Other file systems (s3a://, hdfs://): the bytes come with Spark's `binaryFile`
        # rows, packed into tasks of `size` files' worth of bytes (Spark's default, 128 MB
        # counting 4 MB per file, is a few dozen scans a task).
        total = sum(r["length"] for r in files.select("length").collect())
        split = max(total * size // max(1, len(scan_files)), 1 << 20)
        conf = {"spark.sql.files.maxPartitionBytes": str(split), "spark.sql.files.openCostInBytes": "0"}
        rows = files.select("path", "content").mapInArrow(lambda batches: describe_partition(batches, index, seqs, staging), ddl)
    saved = {k: spark.conf.get(k, None) for k in conf}
    ranges = [
        (p, first, min(messages_per_task, n - first), seqs[p] + first)
        for p, n in sorted(counts.items())
        for first in range(0, n, messages_per_task)
    ]
    if ranges:
        tasks = spark.createDataFrame(ranges, "path string, first_message bigint, message_count bigint, seq bigint")
        tasks = tasks.repartition(len(ranges))
        rows = rows.unionByName(tasks.mapInArrow(lambda batches: describe_ranges(batches, index, staging), ddl))
    try:
        for k, v in conf.items():
            spark.conf.set(k, v)
        rows.write.mode("overwrite").option("compression", "zstd").partitionBy("session").parquet(os.path.join(staging, "scans"))
        status = _status_counts(os.path.join(staging, "scans"))
        toporec._toporec.merge_written(index, staging)
    finally:
        for k, v in saved.items():
            if v is None:
                spark.conf.unset(k)
            else:
                spark.conf.set(k, v)
        shutil.rmtree(staging, ignore_errors=True)
    return {
        "index": index,
        "scans": sum(status.values()),
        "ok": status.get("ok", 0),
        "skipped": status.get("skipped", 0),
        "errors": status.get("error", 0),
    }


def _status_counts(scans: str) -> Dict[str, int]:
    """Scans per status in a written ``scans`` folder (read locally: a few bytes a scan)."""
    import pyarrow.dataset as ds

    table = ds.dataset(scans, format="parquet", partitioning="hive").to_table(columns=["status"])
    return {r["values"]: r["counts"] for r in table.column("status").value_counts().to_pylist()}


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
    ap.add_argument("--scans-per-task", type=int, help="scan files per task (default: a quarter of a core's share, at most 256)")
    ap.add_argument("--read", choices=["auto", "spark"], default="auto", help="who reads the scan files: the tasks when local (auto), or Spark's binaryFile rows")
    ap.add_argument("--messages-per-task", type=int, default=64, help="scans per message-log task (MCAP, bag)")
    ap.add_argument("--master", help="Spark master (default: spark-submit's)")
    ap.add_argument("--verbose", action="store_true", help="keep Spark's INFO log lines (default: warnings only)")
    args = ap.parse_args(argv)
    builder = SparkSession.builder.appName("toporec-index")
    if not args.verbose:
        # Spark's INFO lines (a few hundred a job) would drown the summary.
        builder = builder.config("spark.log.level", "WARN")
    if args.master:
        builder = builder.master(args.master)
    spark = builder.getOrCreate()
    start = time.monotonic()
    result = index_files(spark, args.inputs, args.index, pipeline=args.pipeline, sample=args.sample, scans_per_task=args.scans_per_task, read=args.read, messages_per_task=args.messages_per_task)
    print(summary(result, time.monotonic() - start))
    spark.stop()


def summary(result: Dict[str, Any], seconds: float) -> str:
    """The job's summary in the words of ``toporec run``'s."""
    return "\n".join(
        [
            f"index: {result['index']}",
            f"scans: {result['scans']} read, {result['ok']} indexed, {result['skipped']} skipped, {result['errors']} errors",
            f"wall time: {seconds:.2f} s, {result['scans'] / max(seconds, 1e-9):.1f} scans/s",
        ]
    )


if __name__ == "__main__":
    main()
