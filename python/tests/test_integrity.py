"""Readers against writers: `toporec query`, the Python Index, DuckDB and pyarrow reading the
manifest's file list, and plain globs of the table folders, in a loop while `run --full`,
`compact` and `revectorize` write the same index. Every manifest read sees one whole committed
generation (all 64 scans, never a mix); a glob never sees a file that no commit names."""

import json
import pathlib
import subprocess
import threading
import time

import pyarrow.dataset as ds

import toporec
from conftest import REPO, require

# How long the writers and readers race (the test stays well under a minute on 2 cores).
SECONDS = 15.0
SCANS = 64


def small_pipeline(tmp_path: pathlib.Path) -> pathlib.Path:
    text = (REPO / "pipelines" / "sample.toml").read_text()
    text = text.replace('"../samples/town/velodyne_data"', json.dumps(str(REPO / "samples" / "town" / "velodyne_data")))
    text = text.replace("subsample = 4096", "subsample = 512").replace("b = 50 ", "b = 8 ")
    path = tmp_path / "small.toml"
    path.write_text(text)
    return path


def manifest(index: pathlib.Path):
    m = json.loads((index / "manifest.json").read_text())
    return m["generation"], {f["path"] for f in m["files"]}


def globbed(index: pathlib.Path):
    out = set()
    for table in ("scans", "diagrams", "descriptors"):
        out |= {p.relative_to(index).as_posix() for p in (index / table).rglob("*.parquet")}
    return out


def test_index_info_and_files(sample_index, binary):
    index = toporec.Index(sample_index)
    info = index.info()
    assert info["counts"]["scans"] == SCANS and info["generation"] >= 1
    assert sorted(info["sessions"]) == ["2026-01-01", "2026-01-02"]
    assert info["sessions"]["2026-01-01"]["ok"] == 32
    assert info["methods"]["toporec"]["length"] == 50 and info["methods"]["toporec"]["rows"] == SCANS
    assert "[vectorize]" in info["pipeline"]
    cli = json.loads(subprocess.run([binary, "info", "--index", sample_index, "--json"], check=True, capture_output=True, text=True).stdout)
    assert cli["methods"] == info["methods"] and cli["sessions"] == info["sessions"]
    files = index.files()
    listed = subprocess.run([binary, "info", "--index", sample_index, "--files"], check=True, capture_output=True, text=True)
    assert files == listed.stdout.splitlines()
    _, named = manifest(sample_index)
    assert {pathlib.Path(f).relative_to(sample_index.resolve()).as_posix() for f in files} == named
    scans = index.files("scans")
    assert len(scans) == 2 and all("/scans/" in f for f in scans)
    assert len(index.files("descriptors", method="toporec")) == 2
    # The recipe docs/index-format.md gives for DuckDB and pyarrow.
    duckdb = require("duckdb")
    count = duckdb.sql(f"SELECT count(*) FROM read_parquet({scans}, hive_partitioning = true)").fetchall()[0][0]
    assert count == SCANS
    assert ds.dataset(scans, format="parquet", partitioning="hive").count_rows() == SCANS


def test_readers_race_writers(tmp_path, binary):
    duckdb = require("duckdb")
    pipeline = small_pipeline(tmp_path)
    index = tmp_path / "index"
    subprocess.run([binary, "run", pipeline, "--index", index, "--commit-every", "8", "--no-progress"], check=True, capture_output=True)
    query_scan = sorted((REPO / "samples" / "town" / "velodyne_data" / "2026-01-02" / "velodyne_sync").glob("*.bin"))[5]
    stop = threading.Event()
    failures = []
    counts = {"writes": 0, "query": 0, "index": 0, "duckdb": 0, "pyarrow": 0, "glob": 0, "retries": 0}

    def guarded(name, body):
        def loop():
            try:
                while not stop.is_set():
                    body()
                    counts[name] += 1
            except Exception as e:  # noqa: BLE001 - any failure of a reader or writer is the finding
                failures.append(f"{name}: {type(e).__name__}: {e}")
                stop.set()

        return threading.Thread(target=loop, name=name)

    writes = [
        ["run", pipeline, "--index", index, "--full", "--commit-every", "8", "--no-progress"],
        ["compact", "--index", index],
        ["revectorize", "--index", index, "-b", "8", "-t", "1"],
    ]

    # Every generation the writers commit (each command commits at most once): a file a glob
    # sees must be named by one of them.
    ever_named = set(manifest(index)[1])

    def write():
        cmd = writes[counts["writes"] % len(writes)]
        p = subprocess.run([binary, *cmd], capture_output=True, text=True)
        assert p.returncode == 0, f"{cmd[0]}: {p.stderr}"
        ever_named.update(manifest(index)[1])

    def query():
        p = subprocess.run([binary, "query", "--index", index, query_scan, "-k", "3"], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        assert len(p.stdout.strip().splitlines()) == 4, p.stdout

    def python_index():
        i = toporec.Index(index)
        assert i.scans().num_rows == SCANS
        assert i.descriptors().num_rows == SCANS

    def from_file_list(read):
        # A listed file a later commit replaced is gone: list again and read again.
        for _ in range(50):
            files = toporec.Index(index).files("scans")
            try:
                n = read(files)
            except Exception as e:  # noqa: BLE001 - only a vanished file is retried
                if isinstance(e, FileNotFoundError) or any(s in str(e).lower() for s in ("no such file", "not found", "no files found")):
                    counts["retries"] += 1
                    continue
                raise
            assert n == SCANS, f"{n} rows from one generation's file list"
            return
        raise AssertionError("50 file lists in a row went stale")

    def with_duckdb():
        from_file_list(lambda files: duckdb.sql(f"SELECT count(*) FROM read_parquet({files})").fetchall()[0][0])

    def with_pyarrow():
        from_file_list(lambda files: ds.dataset(files, format="parquet").count_rows())

    def glob():
        # While a commit renames and deletes, a glob may see the superseded generation's files
        # beside the new ones; never a file that no commit names.
        _, m1 = manifest(index)
        seen = globbed(index)
        _, m2 = manifest(index)
        committed = ever_named | m1 | m2
        assert seen <= committed, f"uncommitted files visible to a glob: {sorted(seen - committed)}"

    threads = [guarded("writes", write), guarded("query", query), guarded("index", python_index)]
    threads += [guarded("duckdb", with_duckdb), guarded("pyarrow", with_pyarrow), guarded("glob", glob)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + SECONDS
    while time.monotonic() < deadline and not stop.is_set():
        time.sleep(0.1)
    stop.set()
    for t in threads:
        t.join()
    assert not failures, failures
    for name, n in counts.items():
        if name != "retries":
            assert n >= 2, counts
    print(counts)
    assert subprocess.run([binary, "verify", "--index", index], capture_output=True).returncode == 0


def test_a_damaged_part_is_never_read_and_repair_restores_it(sample_index, binary, tmp_path):
    """A part whose bytes changed after its commit: the Index refuses it by name (with the
    repair to run), the Spark job's merge refuses to take the index's scans from it, and
    `toporec repair` makes the tables equal to the intact ones again."""
    import shutil

    index = tmp_path / "index"
    shutil.copytree(sample_index, index, ignore=shutil.ignore_patterns("searchers"))
    intact = toporec.Index(index).descriptors().sort_by("scan_id")
    part = sorted(toporec.Index(index).files("descriptors", method="toporec"))[0]
    data = bytearray(pathlib.Path(part).read_bytes())
    data[len(data) // 2] ^= 0x04
    pathlib.Path(part).write_bytes(bytes(data))
    for read in (lambda: toporec.Index(index).descriptors(), lambda: toporec.Index(index).query(str(REPO / "samples" / "town" / "velodyne_data" / "2026-01-02"), k=1)):
        try:
            read()
        except ValueError as e:
            assert part in str(e) and "damaged" in str(e) and f"toporec repair --index {index}" in str(e), e
        else:
            raise AssertionError("a damaged part was read")
    # The Spark job's merge opens the index as a writer: it reads the committed scans first.
    staging = tmp_path / "staging"
    staging.mkdir()
    try:
        toporec._toporec.merge_written(str(index), str(staging))
    except ValueError as e:
        assert "damaged" in str(e), e
    else:
        raise AssertionError("merged into a damaged index")
    subprocess.run([binary, "repair", "--index", index], check=True, capture_output=True)
    assert toporec.Index(index).descriptors().sort_by("scan_id").equals(intact)
