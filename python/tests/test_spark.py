"""The Spark job (toporec.spark, local[2]) against `toporec run` with the same codebook: the
same scan and diagram rows, descriptors within 1e-6, the same query answers and Recall@N."""

import json
import shutil
import subprocess

import numpy as np
import pytest

import toporec
from conftest import REPO, data_required, require


@pytest.fixture(scope="module")
def spark():
    require("pyspark")
    if shutil.which("java") is None:
        if data_required():
            pytest.fail("java is not on PATH (Spark needs Java 17)")
        pytest.skip("java is not on PATH")
    from pyspark.sql import SparkSession

    session = (
        SparkSession.builder.master("local[2]")
        .appName("toporec-test")
        .config("spark.ui.enabled", "false")
        .config("spark.sql.shuffle.partitions", "2")
        .getOrCreate()
    )
    session.sparkContext.setLogLevel("ERROR")
    yield session
    session.stop()


@pytest.mark.parametrize("read", ["auto", "spark"])
def test_spark_index_equals_toporec_run(spark, tmp_path, binary, read):
    """Both ways of reading the files: by the tasks (local files, the default) and as Spark's
    `binaryFile` rows (other file systems)."""
    from toporec.spark import index_files

    # The sample with toporec-plus and ScanContext beside TopoRec: every table the job writes.
    text = (REPO / "pipelines" / "sample.toml").read_text().replace('"../samples', f'"{REPO}/samples')
    pipeline = tmp_path / "three.toml"
    pipeline.write_text(text + '\n[descriptors]\nmethods = ["toporec", "toporec-plus", "scancontext"]\n')
    by_run, by_spark = tmp_path / "run", tmp_path / "spark"
    toporec.fit(pipeline, sample=0.5, index=by_run)
    toporec.run(pipeline, index=by_run)
    result = index_files(spark, [REPO / "samples" / "town" / "velodyne_data"], by_spark, pipeline=pipeline, sample=0.5, read=read)
    assert result["scans"] == 64 and result["ok"] == 64, result
    assert not list(by_spark.glob(".spark-*")), "the staging folder is removed"

    a, b = toporec.Index(by_run), toporec.Index(by_spark)
    key = [("scan_id", "ascending")]
    assert a.scans().sort_by(key).equals(b.scans().sort_by(key))
    pairs = key + [("dim", "ascending"), ("birth", "ascending"), ("death", "ascending")]
    assert a.diagrams().sort_by(pairs).equals(b.diagrams().sort_by(pairs))
    assert a.methods() == b.methods() == ["scancontext", "toporec", "toporec-plus"]
    for method in a.methods():
        da, db = a.descriptors(method).sort_by(key), b.descriptors(method).sort_by(key)
        assert da.schema == db.schema, method
        assert da.drop(["descriptor"]).equals(db.drop(["descriptor"])), method
        va = np.stack(da["descriptor"].to_numpy(zero_copy_only=False))
        vb = np.stack(db["descriptor"].to_numpy(zero_copy_only=False))
        np.testing.assert_allclose(vb, va, rtol=0, atol=1e-6, err_msg=method)

    day2 = REPO / "samples" / "town" / "velodyne_data" / "2026-01-02"
    assert a.query(day2, k=5).equals(b.query(day2, k=5))

    verify = subprocess.run([binary, "verify", "--index", by_spark], capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr
    reports = []
    for index in (by_run, by_spark):
        out = tmp_path / f"eval-{index.name}"
        args = ["eval", "places", "--db", index, "--db-session", "2026-01-01", "--query-session", "2026-01-02", "-o", out]
        subprocess.run([binary, *args], check=True, capture_output=True)
        report = json.loads((out / "report.json").read_text())
        reports.append(report["methods"])
    assert reports[0] == reports[1] or _same_recalls(*reports)


def _same_recalls(a, b):
    """Equal reports but for the measured times (`timing_ms`, at every level)."""

    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k != "timing_ms"}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(a) == strip(b)


@pytest.mark.parametrize("read", ["auto", "spark"])
def test_a_bad_file_is_an_error_row(spark, tmp_path, read):
    from toporec.spark import index_files

    pipeline = REPO / "pipelines" / "sample.toml"
    drive = tmp_path / "drive" / "2026-01-01" / "velodyne_sync"
    drive.mkdir(parents=True)
    files = sorted((REPO / "samples" / "town" / "velodyne_data" / "2026-01-01" / "velodyne_sync").glob("*.bin"))[:3]
    for f in files:
        shutil.copy(f, drive / f.name)
    (drive / files[1].name).write_bytes(files[1].read_bytes()[:-5])
    index = tmp_path / "index"
    result = index_files(spark, [tmp_path / "drive"], index, pipeline=pipeline, sample=1.0, read=read)
    assert result["scans"] == 3 and result["errors"] == 1, result
    rows = {r["scan_id"]: r for r in toporec.Index(index).scans().to_pylist()}
    bad = rows[f"2026-01-01/{files[1].stem}"]
    assert bad["status"] == "error" and files[1].name in bad["error"]


def test_mcap_files_split_by_message_ranges(spark, tmp_path, binary):
    """A simulated two-session MCAP drive, split into ranges of 3 messages, gives the index
    `toporec run` gives: the same scan rows (seq, message_index and poses included), the same
    diagram rows, the same descriptors."""
    from toporec.spark import index_files

    drive = tmp_path / "drive"
    subprocess.run(
        [binary, "simulate", "-o", drive, "--format", "mcap", "--sessions", "2", "--scans", "7", "--blocks", "2"],
        check=True,
        capture_output=True,
    )
    logs = sorted((drive / "mcap").glob("*.mcap"))
    assert len(logs) == 2
    sources = "\n".join(
        f'[[sources]]\nkind = "mcap"\nfiles = ["{log}"]\nposes = "{drive / "mcap" / f"groundtruth_{log.stem}.csv"}"\n'
        for log in logs
    )
    pipeline = tmp_path / "mcap.toml"
    pipeline.write_text(
        f'[output]\nindex = "unused"\n\n{sources}\n'
        "[preprocess]\nrange = { max = 60.0 }\nsubsample = 1024\nnormalize = true\n\n"
        '[vectorize]\nb = 8\ndims = [0, 1, 2]\ncontrast = "laplacian"\nseed = 0\n'
    )
    by_run, by_spark = tmp_path / "run", tmp_path / "spark"
    toporec.fit(pipeline, sample=1.0, index=by_run)
    toporec.run(pipeline, index=by_run)
    result = index_files(spark, [drive / "mcap"], by_spark, pipeline=pipeline, sample=1.0, messages_per_task=3)
    assert result["scans"] == 14 and result["ok"] == 14, result

    a, b = toporec.Index(by_run), toporec.Index(by_spark)
    key = [("scan_id", "ascending")]
    sa, sb = a.scans().sort_by(key), b.scans().sort_by(key)
    assert sa.column("message_index").to_pylist() == [i for _ in logs for i in range(7)]
    assert None not in sa.column("pose_x").to_pylist(), "poses joined from each file's ground truth"
    assert sa.equals(sb)
    pairs = key + [("dim", "ascending"), ("birth", "ascending"), ("death", "ascending")]
    assert a.diagrams().sort_by(pairs).equals(b.diagrams().sort_by(pairs))
    assert a.descriptors().sort_by(key).equals(b.descriptors().sort_by(key))


def test_local_listing_equals_binary_file_listing(spark, tmp_path):
    """Local folders are walked by the driver; the files are those Spark's `binaryFile` read
    lists (hidden names skipped, the glob on file names, files given directly)."""
    from toporec.spark import _listing, _local_files, _local_inputs, _uri

    for name in ["a/velodyne_sync/1.bin", "a/velodyne_sync/2.bin", "a/velodyne_sync/notes.txt", "a/.hidden/3.bin",
                 "a/_tmp/4.bin", "a/velodyne_sync/.5.bin", "a/velodyne_sync/_6.bin", "b/deep/er/7.bin", "c/8.bin"]:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"\0" * 16)
    inputs = [str(tmp_path / "a"), f"file:{tmp_path / 'b'}", str(tmp_path / "c" / "8.bin")]
    assert _local_inputs(spark, inputs)
    ours = _local_files(inputs, "*.bin")
    assert ours == sorted(_uri(p) for p in _listing(spark, inputs, "*.bin").inputFiles())
    assert [p.rsplit("/", 1)[1] for p in ours] == ["1.bin", "2.bin", "7.bin", "8.bin"]
    assert not _local_inputs(spark, ["s3a://bucket/logs"]) and not _local_inputs(spark, ["hdfs:/logs"])
    assert not _local_inputs(spark, [str(tmp_path / "*")])
    with pytest.raises(FileNotFoundError, match="missing: no such file or folder"):
        _local_files([str(tmp_path / "missing")], "*.bin")


def test_the_summary_speaks_as_toporec_run(spark, tmp_path, binary):
    """The job prints the lines `toporec run` prints for the same counts, word for word."""
    from toporec.spark import summary

    text = summary({"index": "out/x", "scans": 64, "ok": 62, "skipped": 1, "errors": 1}, 2.0)
    assert text.splitlines() == [
        "index: out/x",
        "scans: 64 read, 62 indexed, 1 skipped, 1 errors",
        "wall time: 2.00 s, 32.0 scans/s",
    ]
    run = subprocess.run([binary, "run", REPO / "pipelines" / "sample.toml", "--index", tmp_path / "i", "--no-progress"], capture_output=True, text=True, check=True)
    ours = [line.split(":")[0] for line in text.splitlines()]
    theirs = [line.split(":")[0] for line in run.stderr.splitlines()]
    assert all(word in theirs for word in ours), (ours, theirs)
    scans = next(line for line in run.stderr.splitlines() if line.startswith("scans:"))
    assert scans == "scans: 64 read, 64 indexed, 0 skipped, 0 errors"


def test_bags_index_as_toporec_run_indexes_them(spark, tmp_path, shared_data):
    """The four real bags of ../shared/data/bags (two ROS 1 files, a rosbag2 sqlite3 folder and
    a rosbag2 MCAP folder): the folders are listed as one log each (not their storage files),
    split into message ranges, and the index equals `toporec run`'s on a `kind = "rosbag"`
    pipeline."""
    from toporec.spark import LOG_GLOBS, _local_files, _logs, index_files

    bags = shared_data / "bags"
    paths = [bags / n for n in ["kitti00_ros1_bz2.bag", "kitti00_ros1_lz4.bag", "kitti00_rosbag2_mcap", "kitti00_rosbag2_sqlite3"]]
    # The folder's every log, each once (the two with odometry among them); the four above are indexed.
    listed = _logs([f for g in LOG_GLOBS for f in _local_files([str(bags)], g)])
    logs = sorted(p.name for p in bags.iterdir() if p.suffix == ".bag" or (p / "metadata.yaml").is_file())
    assert [p.rsplit("/", 1)[1] for p in listed] == logs and set(p.name for p in paths) < set(logs)
    pipeline = tmp_path / "bags.toml"
    pipeline.write_text(
        '[output]\nindex = "unused"\n\n[[sources]]\nkind = "rosbag"\npaths = [' + ", ".join(f'"{p}"' for p in paths) + "]\n\n"
        "[preprocess]\nsubsample = 1024\nnormalize = true\n\n"
        '[vectorize]\nb = 8\ndims = [0, 1, 2]\ncontrast = "laplacian"\nseed = 0\n\n'
        '[descriptors]\nmethods = ["toporec", "scancontext"]\n'
    )
    by_run, by_spark = tmp_path / "run", tmp_path / "spark"
    toporec.fit(pipeline, sample=1.0, index=by_run)
    toporec.run(pipeline, index=by_run)
    result = index_files(spark, paths, by_spark, pipeline=pipeline, sample=1.0, messages_per_task=3)
    assert result["scans"] == 16 and result["ok"] == 16, result

    a, b = toporec.Index(by_run), toporec.Index(by_spark)
    key = [("scan_id", "ascending")]
    sa, sb = a.scans().sort_by(key), b.scans().sort_by(key)
    assert sorted({i.split("/")[0] for i in sa.column("scan_id").to_pylist()}) == [p.name.removesuffix(".bag") for p in paths]
    assert sa.equals(sb)
    pairs = key + [("dim", "ascending"), ("birth", "ascending"), ("death", "ascending")]
    assert a.diagrams().sort_by(pairs).equals(b.diagrams().sort_by(pairs))
    for method in ["toporec", "scancontext"]:
        assert a.descriptors(method).sort_by(key).equals(b.descriptors(method).sort_by(key))
