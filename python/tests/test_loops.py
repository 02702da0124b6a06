"""The online loop detector: the matches of ``toporec loops`` on the same scans, the GIL released."""

import csv
import pathlib
import subprocess
import threading
import time

import numpy as np
import pytest

import toporec


@pytest.fixture(scope="module")
def loops_index(repo: pathlib.Path, tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The sample drive indexed with toporec-plus, ScanContext, RING and RING++."""
    folder = tmp_path_factory.mktemp("loops")
    sessions = repo / "samples" / "town" / "velodyne_data"
    pipeline = folder / "loops.toml"
    pipeline.write_text(
        f'[output]\nindex = "index"\n[[sources]]\nkind = "nclt"\nsessions = ["{sessions.as_posix()}"]\n'
        '[descriptors]\nmethods = ["toporec-plus", "scancontext", "ring", "ring-plus"]\n'
    )
    index = folder / "index"
    toporec.run(pipeline, threads=2, index=index)
    return index


def sample_scans(repo: pathlib.Path):
    """(session, utime, path) of the sample's scans in time order."""
    for session in ("2026-01-01", "2026-01-02"):
        folder = repo / "samples" / "town" / "velodyne_data" / session / "velodyne_sync"
        for path in sorted(folder.glob("*.bin")):
            yield session, int(path.stem), path


@pytest.mark.parametrize("method", ["toporec-plus", "scancontext", "ring", "ring-plus"])
def test_detector_equals_toporec_loops(repo, loops_index, binary, tmp_path, method):
    out = tmp_path / "loops.csv"
    subprocess.run(
        [binary, "loops", "--index", loops_index, "--method", method, "--all", "--threshold", "0.3", "-o", out],
        check=True,
        capture_output=True,
    )
    with open(out, newline="") as f:
        expected = [
            (r["query_scan"], r["matched_scan"], float(r["distance"]), r["accepted"] == "true") for r in csv.DictReader(f)
        ]
    detector = toporec.LoopDetector(method, threshold=0.3, index=loops_index)
    ids = []
    found = []
    for session, utime, path in sample_scans(repo):
        detector.add(toporec.read_points(path), time=utime / 1e6, session=session)
        query = f"{session}/{utime}"
        m = detector.last_match
        if m is not None:
            found.append((query, ids[m["match"]], m["distance"], m["accepted"]))
        ids.append(query)
    assert len(detector) == 64
    assert found and found == expected


def test_default_thresholds_and_errors():
    assert toporec.LoopDetector("toporec-plus").threshold == 0.3619
    assert toporec.LoopDetector("scancontext").threshold == 0.5335
    assert toporec.LoopDetector("ring").threshold == 0.4544
    assert toporec.LoopDetector("ring-plus").threshold == 0.4390
    with pytest.raises(ValueError, match="no default threshold"):
        toporec.LoopDetector("solid")
    with pytest.raises(ValueError, match="unknown method"):
        toporec.LoopDetector("nope", threshold=1.0)
    with pytest.raises(ValueError, match="expected an"):
        toporec.LoopDetector().add(np.zeros((4, 2)))


def test_add_releases_the_gil():
    rng = np.random.default_rng(0)
    # A large scan: its describing takes long enough to see the other thread run meanwhile.
    cloud = np.column_stack([rng.uniform(-70, 70, (2_000_000, 2)), rng.uniform(-2, 10, 2_000_000)])
    detector = toporec.LoopDetector("toporec-plus")
    span = []

    def add():
        start = time.perf_counter()
        detector.add(cloud, time=0.0)
        span.extend([start, time.perf_counter()])

    worker = threading.Thread(target=add)
    ticks = []
    worker.start()
    while worker.is_alive():
        ticks.append(time.perf_counter())
    worker.join()
    start, end = span
    during = sum(start < t < end for t in ticks)
    # Holding the GIL through the call would leave the main thread no step inside it.
    assert end - start > 0.01, "the scan was described too fast to tell"
    assert during > 100, f"{during} main-thread steps during a {end - start:.3f} s add"


@pytest.mark.parametrize("method", ["ring", "ring-plus"])
def test_ring_query_gives_the_scan_itself_with_its_pose(repo, loops_index, method):
    """`Index.query` with RING and RING++: a stored scan finds itself first, with no turn and no
    offset (x_m, y_m, yaw_deg filled as for toporec-plus)."""
    _, _, path = list(sample_scans(repo))[5]
    hits = toporec.Index(loops_index).query([path], k=2, method=method)
    assert hits["scan_id"][0].as_py().endswith(path.stem)
    assert hits["yaw_deg"][0].as_py() == 0.0
    assert (hits["x_m"][0].as_py(), hits["y_m"][0].as_py()) == (0.0, 0.0)
    assert hits["distance"][0].as_py() <= hits["distance"][1].as_py()


def test_loops_of_a_bag_equal_the_command(repo, binary, tmp_path):
    """toporec.loops on the sample bag: the rows `toporec loops samples/drive.bag` writes, from
    the same index, verified; the second call computes nothing new and answers the same."""
    import pyarrow.parquet as pq

    bag = repo / "samples" / "drive.bag"
    index = tmp_path / "index"
    table = toporec.loops(bag, index=index, threads=2)
    out = tmp_path / "command.parquet"
    subprocess.run(
        [binary, "loops", bag, "--index", tmp_path / "command-index", "-o", out, "--no-progress", "-t", "2"],
        check=True,
        capture_output=True,
    )
    expected = pq.read_table(out)
    assert table.schema.names == expected.schema.names
    assert table.to_pylist() == expected.to_pylist()
    accepted = [r for r in table.to_pylist() if r["accepted"]]
    assert len(accepted) >= 10, len(accepted)
    assert all(r["verified"] is not None for r in accepted)
    assert toporec.loops(bag, index=index, threads=1).to_pylist() == table.to_pylist()


def test_loops_of_a_missing_log_raise_naming_it(tmp_path):
    missing = tmp_path / "nowhere.bag"
    with pytest.raises(Exception, match="nowhere.bag"):
        toporec.loops(missing, index=tmp_path / "index")
