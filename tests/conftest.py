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


def published_scene(flat_root: Path, scene: str):
    """A published scene's reference map and queries, built from the published data as the
    workflow builds them (split seed 0)."""
    from flatlandia import geo, io
    from flatlandia.classes import CLASSES
    from flatlandia.data import queries, recover, reference_map

    lonlat, classes = io.read_reference_map(flat_root / f"individual_reference_maps/map_{scene}.json", len(CLASSES))
    frame = geo.frame_for(lonlat)
    ref = reference_map.reference_table(scene, lonlat, classes, CLASSES, frame)
    local = io.read_local_maps(flat_root / "local_maps.json", scene)
    rec = recover.recover_scene(scene, lonlat, classes, local)
    split = queries.split_queries(list(rec["token"]), 0, salt=scene)
    return ref, queries.build_queries(scene, rec, ref, local, frame, split)


@pytest.fixture(scope="session")
def scene9(flat_root):
    """Scene 9's reference map and queries (shared by the fine-stage and coarse-solver tests)."""
    return published_scene(flat_root, "9")
