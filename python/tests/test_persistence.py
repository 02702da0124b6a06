"""alpha_persistence and AlphaComplex against GUDHI 3.13 (from PyPI) and its fixtures."""

import csv
import math

import numpy as np
import pytest

import toporec
from conftest import require

CLOUDS = [
    "uniform_cube_500",
    "uniform_cube_4096",
    "two_spheres_800",
    "torus_1000",
    "lidar_like_4096",
    "lattice_6x6x6_degenerate",
    "duplicates_300x2",
    "planar_400_degenerate",
]

# GUDHI's `safe` values differ from correctly rounded ones by up to 2.2e-10 relative; toporec's
# equal GUDHI's `exact`, so the tolerance is 1e-9 relative.
REL = 1e-9


def read_cloud(fixtures, name):
    return np.loadtxt(fixtures / "clouds" / f"{name}.csv", delimiter=",", skiprows=1)


def read_fixture_diagram(fixtures, name):
    out = {0: [], 1: [], 2: []}
    with open(fixtures / "diagrams" / f"{name}.csv") as f:
        for row in csv.DictReader(f):
            out[int(row["dim"])].append((float(row["birth"]), float(row["death"])))
    return {d: np.array(sorted(v), dtype=np.float64).reshape(-1, 2) for d, v in out.items()}


def assert_same(ours, theirs, what):
    assert ours.shape == theirs.shape, f"{what}: {ours.shape} pairs vs {theirs.shape}"
    a = ours[np.lexsort((ours[:, 1], ours[:, 0]))]
    b = theirs[np.lexsort((theirs[:, 1], theirs[:, 0]))]
    np.testing.assert_array_equal(np.isinf(a), np.isinf(b), err_msg=what)
    finite = np.isfinite(b)
    np.testing.assert_allclose(a[finite], b[finite], rtol=REL, atol=0, err_msg=what)


@pytest.mark.parametrize("name", CLOUDS)
def test_equals_gudhi_fixture(fixtures, name):
    ours = toporec.alpha_persistence(read_cloud(fixtures, name))
    theirs = read_fixture_diagram(fixtures, name)
    for dim in (0, 1, 2):
        assert_same(ours[dim], theirs[dim], f"{name} H{dim}")


@pytest.mark.parametrize("name", ["uniform_cube_500", "two_spheres_800", "lattice_6x6x6_degenerate"])
def test_equals_gudhi_live(fixtures, name):
    gudhi = require("gudhi")
    points = read_cloud(fixtures, name)
    st = gudhi.AlphaComplex(points=points, precision="exact").create_simplex_tree()
    st.persistence()
    ac = toporec.AlphaComplex(points).create_simplex_tree()
    ours = ac.persistence()
    assert len(ours) == len(st.persistence())
    for dim in (0, 1, 2):
        assert_same(ac.persistence_intervals_in_dimension(dim), st.persistence_intervals_in_dimension(dim), f"{name} H{dim}")
    # GUDHI's order: dimension descending, then length descending.
    keys = [(-d, -(b[1] - b[0])) for d, b in ours]
    assert keys == sorted(keys)
    assert ac.num_vertices() == st.num_vertices()
    if name != "lattice_6x6x6_degenerate":  # a degenerate Delaunay complex is not unique
        assert ac.num_simplices() == st.num_simplices()
    assert ac.dimension() == st.dimension()


def test_radii_are_square_roots(fixtures):
    points = read_cloud(fixtures, "torus_1000")
    sq = toporec.alpha_persistence(points)
    r = toporec.alpha_persistence(points, squared=False)
    for dim in (0, 1, 2):
        np.testing.assert_allclose(r[dim], np.sqrt(sq[dim]), rtol=1e-15)


def test_dims_and_lists():
    octahedron = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    d = toporec.alpha_persistence(octahedron, dims=(2,))
    assert list(d) == [2]
    assert d[2].tolist() == [[2 / 3, 1.0]]
    assert toporec.alpha_persistence(octahedron)[1].shape == (7, 2)


def test_batch_equals_single(fixtures):
    clouds = [read_cloud(fixtures, n) for n in ("uniform_cube_500", "torus_1000", "two_spheres_800")]
    batch = toporec.alpha_persistence_batch(clouds)
    for c, b in zip(clouds, batch):
        single = toporec.alpha_persistence(c)
        for dim in (0, 1, 2):
            np.testing.assert_array_equal(single[dim], b[dim])


@pytest.mark.parametrize(
    "points, message",
    [
        ([[0, 0, math.nan], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "not finite"),
        ([[0, 0, math.inf], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "not finite"),
        (np.zeros((10, 2)), "(n, 3)"),
        (np.zeros((10,)), "(n, 3)"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "at least 4"),
        ([["a", "b", "c"]] * 4, "float64"),
    ],
)
def test_bad_input_raises_value_error(points, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        toporec.alpha_persistence(points)
    with pytest.raises(ValueError):
        toporec.AlphaComplex(points).persistence()


def test_batch_names_the_bad_cloud():
    good = np.random.default_rng(1).random((50, 3))
    bad = good.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="cloud 1"):
        toporec.alpha_persistence_batch([good, bad])


def test_help_shows_the_api():
    assert "(k, 2)" in toporec.alpha_persistence.__doc__
    assert toporec.AlphaComplex.__doc__ and toporec.Atol.__doc__ and toporec.Index.__doc__


def test_located_pairs_are_the_diagram_with_where_each_class_dies(fixtures):
    points = read_cloud(fixtures, "uniform_cube_500")
    pairs, where = toporec.alpha_persistence_located(points)
    assert pairs.shape == where.shape and pairs.shape[1] == 3
    diagram = toporec.alpha_persistence(points)
    for dim in (0, 1, 2):
        mine = pairs[pairs[:, 0] == dim][:, 1:]
        mine = mine[np.lexsort((mine[:, 1], mine[:, 0]))]
        assert np.array_equal(mine, diagram[dim]), f"H{dim}: the same pairs, bit for bit"
    # One class never dies and has no place; every other dies at the centroid of a simplex of
    # the cloud, so inside its bounding box.
    essential = np.isinf(pairs[:, 2])
    assert essential.sum() == 1 and np.isnan(where[essential]).all()
    finite = where[~essential]
    assert np.isfinite(finite).all()
    assert (finite >= points.min(axis=0)).all() and (finite <= points.max(axis=0)).all()
    with pytest.raises(ValueError, match="point 3 is not finite"):
        toporec.alpha_persistence_located(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]]))
