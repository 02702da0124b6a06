"""Shared fixtures: the repository's GUDHI fixtures and a sample index made once per session."""

import importlib
import os
import pathlib

import pytest

import toporec

REPO = pathlib.Path(__file__).resolve().parents[2]
FIXTURES = REPO / "tests" / "fixtures"


@pytest.fixture(scope="session")
def repo() -> pathlib.Path:
    return REPO


@pytest.fixture(scope="session")
def fixtures() -> pathlib.Path:
    return FIXTURES


@pytest.fixture(scope="session")
def sample_index(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The sample job (pipelines/sample.toml) indexed into a fresh folder."""
    index = tmp_path_factory.mktemp("sample") / "index"
    summary = toporec.run(REPO / "pipelines" / "sample.toml", threads=2, index=index, full=True)
    assert summary["scans"]["indexed"] == 64, summary
    return index


def data_required() -> bool:
    """Whether missing data or tools fail a test instead of skipping it: TOPOREC_REQUIRE_DATA
    set, not empty and not 0 (as the Rust tests read it; CI sets it to 1)."""
    value = os.environ.get("TOPOREC_REQUIRE_DATA", "")
    return value not in ("", "0")


def require(module: str):
    """The module, or a skip (a failure with TOPOREC_REQUIRE_DATA=1, as in CI)."""
    try:
        return importlib.import_module(module)
    except ImportError:
        if data_required():
            raise
        pytest.skip(f"{module} is not installed")


@pytest.fixture(scope="session")
def binary() -> pathlib.Path:
    """The release binary the README builds, or a skip (a failure with TOPOREC_REQUIRE_DATA=1)."""
    path = REPO / "target" / "release" / "toporec"
    if not path.exists():
        if data_required():
            pytest.fail(f"{path} is missing: build it with `cargo build --release`")
        pytest.skip(f"{path} is missing (cargo build --release)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> pathlib.Path:
    """``../shared/data`` beside the repository, or a skip (a failure with TOPOREC_REQUIRE_DATA=1)."""
    path = REPO.parent / "shared" / "data"
    if not path.is_dir():
        if data_required():
            pytest.fail(f"{path} is missing")
        pytest.skip(f"{path} is missing")
    return path
