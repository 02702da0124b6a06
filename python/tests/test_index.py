"""Index tables against pyarrow's own reading of the Parquet files; queries; describe_batch
against the rows `toporec run` wrote."""

import csv
import io
import pathlib
import subprocess

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import toporec
from conftest import REPO


def read_with_pyarrow(index: pathlib.Path, table: str, method: str = "") -> pa.Table:
    folder = index / table / (f"method={method}" if method else "")
    parts = []
    for part in sorted(folder.glob("session=*/*.parquet")):
        t = pq.read_table(part)
        session = part.parent.name.removeprefix("session=")
        parts.append(t.append_column(pa.field("session", pa.string(), nullable=False), pa.array([session] * t.num_rows, pa.string())))
    return pa.concat_tables(parts)


def same(ours: pa.Table, theirs: pa.Table, keys):
    assert ours.schema.remove_metadata().equals(theirs.schema.remove_metadata()), (ours.schema, theirs.schema)
    order = [(k, "ascending") for k in keys]
    assert ours.sort_by(order).equals(theirs.sort_by(order))


def test_tables_equal_pyarrow(sample_index):
    index = toporec.Index(sample_index)
    assert index.methods() == ["toporec"]
    scans = index.scans()
    assert scans.num_rows == 64
    same(scans, read_with_pyarrow(sample_index, "scans"), ["scan_id"])
    same(index.diagrams(), read_with_pyarrow(sample_index, "diagrams"), ["scan_id", "dim", "birth", "death"])
    same(index.descriptors(), read_with_pyarrow(sample_index, "descriptors", "toporec"), ["scan_id"])


def test_bad_index_raises(tmp_path):
    with pytest.raises(ValueError, match="no such index"):
        toporec.Index(tmp_path / "missing")
    (tmp_path / "scans" / "session=a").mkdir(parents=True)
    (tmp_path / "scans" / "session=a" / "part-000000.parquet").write_bytes(b"not parquet")
    with pytest.raises(ValueError, match="part-000000.parquet"):
        toporec.Index(tmp_path).scans()


def sample_files():
    root = REPO / "samples" / "town" / "velodyne_data"
    return sorted(root.glob("*/velodyne_sync/*.bin"))


def test_query_paths_match_the_cli(sample_index, tmp_path, binary):
    day2 = REPO / "samples" / "town" / "velodyne_data" / "2026-01-02"
    table = toporec.Index(sample_index).query(day2, k=3)
    assert table.column_names == "query_id,rank,scan_id,session,distance,pose_x,pose_y,pose_z,yaw_deg,x_m,y_m".split(",")
    first = table.filter(pa.compute.equal(table["rank"], 1))
    assert first["query_id"].to_pylist() == first["scan_id"].to_pylist()
    assert max(first["distance"].to_pylist()) == 0.0
    out = tmp_path / "hits.csv"
    subprocess.run([binary, "query", "--index", sample_index, "-k", "3", "--out", out, day2], check=True, capture_output=True)
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert len(rows) == table.num_rows
    for row, ours in zip(rows, table.to_pylist()):
        assert row["query_id"] == ours["query_id"] and int(row["rank"]) == ours["rank"]
        assert row["scan_id"] == ours["scan_id"] and row["session"] == ours["session"]
        assert float(row["distance"]) == ours["distance"]


def decode_nclt(path):
    a = np.frombuffer(path.read_bytes(), dtype=[("x", "<u2"), ("y", "<u2"), ("z", "<u2"), ("i", "u1"), ("l", "u1")])
    return np.stack([a[c] * 0.005 - 100.0 for c in "xyz"], axis=1)


def test_query_points(sample_index):
    path = sample_files()[40]
    table = toporec.Index(sample_index).query([decode_nclt(path)], k=5)
    assert table["query_id"].to_pylist() == ["query/0"] * 5
    assert table["rank"].to_pylist() == [1, 2, 3, 4, 5]
    d = table["distance"].to_pylist()
    assert d == sorted(d)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        toporec.Index(sample_index).query([np.zeros((5, 2))])


def test_describe_batch_gives_the_rows_run_wrote(sample_index):
    index = toporec.Index(sample_index)
    scans = index.scans()
    by_path = {p: s for p, s in zip(scans["source_path"].to_pylist(), scans["seq"].to_pylist())}
    files = sample_files()
    batch = pa.table(
        {
            "path": [str(f) for f in files],
            "content": [f.read_bytes() for f in files],
            "seq": pa.array([by_path[str(f)] for f in files], pa.uint64()),
        }
    )
    out = toporec.describe_batch(batch, sample_index)
    same(out["scans"], scans, ["scan_id"])
    same(out["diagrams"], index.diagrams(), ["scan_id", "dim", "birth", "death"])
    assert list(out["descriptors"]) == ["toporec"]
    same(out["descriptors"]["toporec"], index.descriptors(), ["scan_id"])


def test_describe_batch_writes_the_rows_run_wrote(sample_index, tmp_path):
    # Both sessions' scans, more than one streaming chunk (16 per engine thread).
    files = sample_files()
    assert len(files) > 32 and len({f.parents[1] for f in files}) == 2
    out = toporec.describe_batch(pa.table({"path": [str(f) for f in files]}), sample_index, write_to=tmp_path, part_name="part")
    assert out["diagrams"].num_rows == 0 and out["descriptors"]["toporec"].num_rows == 0
    sessions = sorted({f.parents[1].name for f in files})
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.parquet")) == sorted(
        [f"diagrams/session={s}/part.parquet" for s in sessions] + [f"descriptors/method=toporec/session={s}/part.parquet" for s in sessions]
    )
    index = toporec.Index(sample_index)
    same(read_with_pyarrow(tmp_path, "diagrams"), index.diagrams(), ["scan_id", "dim", "birth", "death"])
    same(read_with_pyarrow(tmp_path, "descriptors", "toporec"), index.descriptors(), ["scan_id"])


def test_describe_batch_bad_rows_become_error_rows(sample_index):
    good = sample_files()[0]
    batch = pa.table(
        {
            "path": [str(good), str(good.with_name("not-a-time.bin")), "somewhere/else.xyz"],
            "content": [good.read_bytes()[:-3], good.read_bytes(), b"\x00" * 16],
        }
    )
    out = toporec.describe_batch(batch, sample_index)
    rows = out["scans"].to_pylist()
    assert [r["status"] for r in rows] == ["error", "error", "error"]
    assert "velodyne_sync/1767261600000000.bin" in rows[0]["error"]
    assert "not a utime" in rows[1]["error"]
    assert "unknown scan file format" in rows[2]["error"]
    assert out["diagrams"].num_rows == 0 and out["descriptors"]["toporec"].num_rows == 0


def test_describe_batch_points(sample_index):
    path = sample_files()[3]
    points = decode_nclt(path)
    batch = pa.table({"path": ["mem"], "scan_id": ["drive/1"], "points": [points.ravel().tolist()]})
    out = toporec.describe_batch(batch, sample_index)
    row = out["scans"].to_pylist()[0]
    assert row["status"] == "ok" and row["session"] == "drive" and row["raw_points"] == len(points)
    assert out["descriptors"]["toporec"].num_rows == 1


def test_describe_batch_reads_files_from_their_paths(sample_index):
    """Rows without bytes are read by the engine from `path`, giving the rows the bytes give;
    a file that cannot be read is an error row naming it."""
    files = sample_files()[:4]
    with_bytes = toporec.describe_batch(pa.table({"path": [str(f) for f in files], "content": [f.read_bytes() for f in files]}), sample_index)
    by_path = toporec.describe_batch(pa.table({"path": [str(f) for f in files]}), sample_index)
    for table in ("scans", "diagrams"):
        assert by_path[table].equals(with_bytes[table])
    assert by_path["descriptors"]["toporec"].equals(with_bytes["descriptors"]["toporec"])
    missing = files[0].with_name("1767261600000001.bin")
    rows = toporec.describe_batch(pa.table({"path": [str(missing)]}), sample_index)["scans"].to_pylist()
    assert rows[0]["status"] == "error" and f"{missing}: cannot read" in rows[0]["error"], rows


@pytest.fixture(scope="module")
def iris_index(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The sample job with LiDAR-Iris beside TopoRec: its descriptors are bytes (uint8)."""
    folder = tmp_path_factory.mktemp("iris")
    text = (REPO / "pipelines" / "sample.toml").read_text().replace('"../', f'"{REPO.as_posix()}/')
    text += '\n[descriptors]\nmethods = ["toporec", "lidar-iris"]\n'
    pipeline = folder / "iris.toml"
    pipeline.write_text(text)
    index = folder / "index"
    summary = toporec.run(pipeline, threads=2, index=index, full=True)
    assert summary["scans"]["indexed"] == 64, summary
    return index


def test_lidar_iris_is_stored_as_bytes_and_described_and_queried_alike(iris_index):
    index = toporec.Index(iris_index)
    assert index.methods() == ["lidar-iris", "toporec"]
    stored = index.descriptors("lidar-iris")
    assert stored.schema.field("descriptor").type == pa.list_(pa.field("item", pa.uint8(), False), 72000)
    same(stored, read_with_pyarrow(iris_index, "descriptors", "lidar-iris"), ["scan_id"])
    files = sample_files()
    out = toporec.describe_batch(pa.table({"path": [str(f) for f in files]}), iris_index)
    assert sorted(out["descriptors"]) == ["lidar-iris", "toporec"]
    same(out["descriptors"]["lidar-iris"], stored, ["scan_id"])
    # A stored scan, queried, is its own nearest at distance 0 and yaw 0.
    hits = index.query([files[3]], k=1, method="lidar-iris")
    assert hits["scan_id"][0].as_py().endswith(files[3].stem)
    assert hits["distance"][0].as_py() == 0.0 and hits["yaw_deg"][0].as_py() == 0.0


def test_descriptors_of_an_index_of_toporec_plus(tmp_path):
    """What `toporec.loops` makes holds toporec-plus alone: descriptors() reads it, an unknown
    method is an error naming the ones the index holds."""
    index = tmp_path / "drive"
    toporec.loops(REPO / "samples" / "drive.bag", index=index, verify=False, threads=2)
    i = toporec.Index(index)
    assert i.methods() == ["toporec-plus"]
    plus = i.descriptors()
    assert plus.num_rows == 96
    assert plus.equals(i.descriptors("toporec-plus"))
    with pytest.raises(Exception, match=r"no descriptors of method `scancontext` \(its methods: toporec-plus\)"):
        i.descriptors("scancontext")


def test_readme_python_snippet_runs_as_written(tmp_path, monkeypatch):
    """The README's Python block, as written, in a scratch copy of the repository where the
    README's first command has run."""
    import shutil

    readme = (REPO / "README.md").read_text()
    block = readme.split("```python\n", 1)[1].split("```", 1)[0]
    shutil.copytree(REPO / "samples", tmp_path / "samples")
    shutil.copytree(REPO / "pipelines", tmp_path / "pipelines")
    monkeypatch.chdir(tmp_path)
    toporec.run("pipelines/sample.toml", threads=2)
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)
    assert scope["vectors"].shape == (8, 8)
    assert set(scope["diagram"]) == {0, 1, 2}
