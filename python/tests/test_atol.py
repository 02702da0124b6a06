"""Atol against gudhi.representations.Atol, and its scikit-learn behaviour."""

import json

import numpy as np
import pytest

import toporec
from conftest import require


def diagrams_of(fixtures, names, dim=2):
    out = []
    for n in names:
        points = np.loadtxt(fixtures / "clouds" / f"{n}.csv", delimiter=",", skiprows=1)
        d = toporec.alpha_persistence(points, dims=(dim,))[dim]
        out.append(d[np.isfinite(d[:, 1])])
    return out


NAMES = ["uniform_cube_500", "two_spheres_800", "torus_1000", "lidar_like_4096"]


@pytest.mark.parametrize("contrast", ["gaussian", "laplacian", "indicator"])
@pytest.mark.parametrize("weighting", ["cloud", "iidproba"])
def test_transform_equals_gudhi_for_the_same_centres(fixtures, contrast, weighting):
    require("sklearn")
    representations = require("gudhi.representations")
    from sklearn.cluster import KMeans

    diagrams = diagrams_of(fixtures, NAMES)
    theirs = representations.Atol(quantiser=KMeans(n_clusters=8, random_state=0, n_init=3), contrast=contrast, weighting_method=weighting)
    theirs.fit(diagrams)
    ours = toporec.Atol(b=8, contrast=contrast, weighting=weighting)
    ours.centers_, ours.inertias_ = theirs.centers, theirs.inertias
    # Each term within an ulp or two of GUDHI's: 1e-12 relative.
    np.testing.assert_allclose(ours.transform(diagrams), theirs.transform(diagrams), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(ours(diagrams[1]), theirs(diagrams[1]), rtol=1e-12)


def test_transform_equals_the_fixture_vectors(fixtures):
    ref = json.loads((fixtures / "atol" / "atol_fixed_centers.json").read_text())
    names = sorted(next(iter(ref["vectors"].values())).keys())
    diagrams = diagrams_of(fixtures, names, ref["diagram_dim"])
    for contrast, vectors in ref["vectors"].items():
        atol = toporec.Atol(b=len(ref["centers"]), contrast=contrast)
        atol.centers_, atol.inertias_ = np.array(ref["centers"]), np.array(ref["inertias"])
        got = atol.transform(diagrams)
        want = np.array([vectors[n] for n in names])
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_fit_is_deterministic_and_sorted(fixtures):
    diagrams = diagrams_of(fixtures, NAMES)
    a = toporec.Atol(b=6, seed=3).fit(diagrams)
    b = toporec.Atol(b=6, seed=3).fit(diagrams)
    np.testing.assert_array_equal(a.centers_, b.centers_)
    assert a.centers_.shape == (6, 2) and a.inertias_.shape == (6,)
    keys = [(c[1], c[0]) for c in a.centers_]
    assert keys == sorted(keys)
    assert a.points_seen_ == sum(len(d) for d in diagrams)


def test_sklearn_clone_and_pipeline(fixtures):
    require("sklearn")
    from sklearn.base import clone
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler

    atol = toporec.Atol(b=5, contrast="gaussian", seed=1)
    c = clone(atol)
    assert c.get_params() == atol.get_params() and c is not atol
    c.set_params(b=4)
    assert c.b == 4 and atol.b == 5
    diagrams = diagrams_of(fixtures, NAMES)
    pipe = Pipeline([("atol", toporec.Atol(b=4)), ("scale", StandardScaler())])
    out = pipe.fit_transform(diagrams)
    assert out.shape == (len(diagrams), 4)
    np.testing.assert_allclose(out.mean(axis=0), 0, atol=1e-9)


def test_save_load_round_trip(tmp_path, fixtures):
    diagrams = diagrams_of(fixtures, NAMES)
    atol = toporec.Atol(b=5, contrast="indicator", seed=2).fit(diagrams)
    codebook_id = atol.save(tmp_path / "codebook.json")
    assert len(codebook_id) == 16
    text = json.loads((tmp_path / "codebook.json").read_text())
    assert text["format"] == "toporec-codebook" and text["dims"] == "paper"
    back = toporec.Atol.load(tmp_path / "codebook.json")
    assert back.get_params() == atol.get_params()
    np.testing.assert_array_equal(back.transform(diagrams), atol.transform(diagrams))


def test_too_few_points_fill_with_inf_centres():
    atol = toporec.Atol(b=4).fit([np.array([[0.0, 1.0], [0.5, 2.0]])])
    assert np.isinf(atol.centers_[2:]).all()


def test_paper_descriptor_uses_the_rule(fixtures):
    clouds = [np.loadtxt(fixtures / "clouds" / f"{n}.csv", delimiter=",", skiprows=1) for n in NAMES]
    full = toporec.alpha_persistence_batch(clouds)
    planar = toporec.alpha_persistence(np.loadtxt(fixtures / "clouds" / "planar_400_degenerate.csv", delimiter=",", skiprows=1))
    paper = toporec.PaperDescriptor(b=6).fit(full)
    np.testing.assert_array_equal(paper.dims_used(full + [planar]), [2, 2, 2, 2, 1])
    plain = toporec.Atol(b=6).fit([d[2] for d in full])
    np.testing.assert_array_equal(paper.centers_, plain.centers_)
    np.testing.assert_array_equal(paper.transform([planar]), plain.transform([planar[1]]))


def test_bad_parameters_raise_value_error():
    with pytest.raises(ValueError, match="contrast"):
        toporec.Atol(contrast="cosine").fit([np.zeros((3, 2))])
    with pytest.raises(ValueError, match="b:"):
        toporec.Atol(b=0).fit([np.zeros((3, 2))])
    with pytest.raises(ValueError, match=r"\(k, 2\)"):
        toporec.Atol(b=2).fit([np.zeros((3, 3))])
    with pytest.raises(ValueError, match="not fitted"):
        toporec.Atol().transform([np.zeros((3, 2))])
