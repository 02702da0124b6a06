"""toporec.read_scans: the scans of bags, rosbag2 folders and MCAPs as a run reads them."""

import numpy as np
import pytest

import toporec


def test_every_bag_yields_the_mcaps_scans(shared_data):
    want = list(toporec.read_scans(shared_data / "mcap" / "kitti_ros2_cdr.mcap"))
    assert [s["message_index"] for s in want] == [0, 1, 2, 3]
    assert all("error" not in s for s in want)
    bags = shared_data / "bags"
    for path in [
        bags / "kitti00_ros1_bz2.bag",
        bags / "kitti00_ros1_lz4.bag",
        bags / "kitti00_rosbag2_sqlite3",
        bags / "kitti00_rosbag2_mcap",
    ]:
        got = list(toporec.read_scans(path, topic="/velodyne_points"))
        assert [s["scan_id"] for s in got] == [f"{path.stem}/{i:06d}" for i in range(4)]
        for g, w in zip(got, want):
            assert g["points"].shape == w["points"].shape and g["points"].dtype == np.float64
            assert np.array_equal(g["points"], w["points"]), path
            assert np.array_equal(g["intensity"], w["intensity"]), path
            assert g["utime"] == w["utime"]


def test_a_file_named_as_a_log_that_is_none_and_not_a_log_are_refused(tmp_path):
    # Judged by its content, as the command line judges it: what it is not, and what was found.
    bad = tmp_path / "garbage.db3"
    bad.write_bytes(b"SQLite format 3\0" + b"\xa5" * 4096)
    with pytest.raises(ValueError, match=r"garbage.db3: not a rosbag2 .db3 file: a SQLite header, and no database"):
        toporec.read_scans(bad)
    cloud = tmp_path / "cloud.csv"
    cloud.write_text("x,y,z\n1,2,3\n")
    with pytest.raises(ValueError, match="read_points"):
        toporec.read_scans(cloud)
