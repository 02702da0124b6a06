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
    assert toporec.LoopDetector("toporec-plus").threshold == 0.3289
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


def test_loops_give_the_maps_corrected_poses_as_the_command_writes_them(repo, binary, tmp_path):
    """toporec.loops(with_poses=True): the corrected_poses table, one row per scan of the map,
    equal to the command's TUM file; with no_optimize=True, no rows."""
    bag = repo / "samples" / "drive.bag"
    index = tmp_path / "index"
    loops, poses = toporec.loops(bag, index=index, threads=2, with_poses=True)
    assert poses.schema.names == ["method", "session", "scan_id", "time", "x", "y", "z", "qx", "qy", "qz", "qw"]
    declared = toporec._table(toporec._toporec.table_schema("corrected_poses")).schema
    assert poses.schema.remove_metadata() == declared
    assert poses.num_rows == 96 and set(poses["session"].to_pylist()) == {"drive"}
    assert all(r["in_map"] for r in loops.to_pylist() if r["accepted"])
    out = tmp_path / "loops.csv"
    subprocess.run(
        [binary, "loops", bag, "--index", index, "-o", out, "--no-progress", "-t", "2"],
        check=True,
        capture_output=True,
    )
    tum = np.loadtxt(tmp_path / "loops.drive.tum")
    columns = ["time", "x", "y", "z", "qx", "qy", "qz", "qw"]
    got = np.column_stack([poses[c].to_numpy() for c in columns])
    # The TUM file's 6 (positions, times) and 9 (quaternions) decimals.
    np.testing.assert_allclose(got[:, :4], tum[:, :4], atol=1e-6)
    np.testing.assert_allclose(got[:, 4:], tum[:, 4:], atol=1e-9)
    _, none = toporec.loops(bag, index=index, threads=2, with_poses=True, no_optimize=True)
    assert none.num_rows == 0 and none.schema == poses.schema


def test_optimize_a_graph_as_the_command_does(repo, binary, tmp_path):
    """toporec.optimize: the optimized vertices and cost of `toporec optimize`, written when asked;
    a malformed line raises naming the file and the line's number."""
    bag = repo / "samples" / "drive.bag"
    graph = tmp_path / "graph.g2o"
    toporec.loops(bag, index=tmp_path / "index", threads=2, g2o=graph, no_optimize=True)
    graph = tmp_path / "graph.toporec-plus.g2o"
    out = tmp_path / "python.g2o"
    done = toporec.optimize(graph, out=out, robust=True)
    assert done.kind == "SE(3)" and done.rejected == []
    assert done.cost_after < done.cost_before
    assert done.poses.schema.names == ["id", "x", "y", "z", "qx", "qy", "qz", "qw"]
    assert done.poses.num_rows == 96 and done.poses["id"].to_pylist() == list(range(96))
    command = tmp_path / "command.g2o"
    said = subprocess.run(
        [binary, "optimize", graph, "-o", command, "--robust"], check=True, capture_output=True, text=True
    ).stdout
    assert out.read_text() == command.read_text()
    assert f"→ {done.cost_after:.6f} in {done.iterations} iterations" in said
    vertices = [line.split() for line in out.read_text().splitlines() if line.startswith("VERTEX_SE3:QUAT")]
    np.testing.assert_allclose(
        done.poses.drop_columns(["id"]).to_pandas().to_numpy(), [[float(w) for w in v[2:]] for v in vertices]
    )
    assert toporec.optimize(graph, robust=True).poses == done.poses  # out=None: nothing written
    assert done.cost_start is None
    chordal = toporec.optimize(graph, out=tmp_path / "chordal.g2o", start="chordal")
    said = subprocess.run(
        [binary, "optimize", graph, "-o", tmp_path / "command-chordal.g2o", "--start", "chordal"],
        check=True, capture_output=True, text=True,
    ).stdout
    assert (tmp_path / "chordal.g2o").read_text() == (tmp_path / "command-chordal.g2o").read_text()
    assert f"→ {chordal.cost_start:.6f} (chordal start) → {chordal.cost_after:.6f}" in said
    with pytest.raises(ValueError, match="start"):
        toporec.optimize(graph, start="middle")
    bad = tmp_path / "bad.g2o"
    bad.write_text(graph.read_text() + "EDGE_SE3:QUAT 0 1 oops\n")
    with pytest.raises(ValueError, match=rf"bad\.g2o:{len(graph.read_text().splitlines()) + 1}: expected 28 numbers"):
        toporec.optimize(bad)


def test_loops_of_a_missing_log_raise_naming_it(tmp_path):
    missing = tmp_path / "nowhere.bag"
    with pytest.raises(Exception, match="nowhere.bag"):
        toporec.loops(missing, index=tmp_path / "index")
