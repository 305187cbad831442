"""Shared fixtures: the real published data (../shared/flatlandia) and the repo root."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root() -> Path:
    return Path(os.environ.get("FLATLANDIA_ROOT", REPO.parent / "shared" / "flatlandia")).resolve()


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def flat_root() -> Path:
    root = data_root()
    if not (root / "local_maps.json").exists():
        pytest.fail(f"the published Flatlandia data is needed at {root} (set FLATLANDIA_ROOT)")
    return root


@pytest.fixture(scope="session")
def all_local_maps(flat_root):
    from flatlandia import io

    return io.read_json(flat_root / "local_maps.json")
