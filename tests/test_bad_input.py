"""Bad input gets an error naming the file and the problem, and leaves no half-written output."""

import json
import math
import os

import pandas as pd
import pytest

from flatlandia import config
from flatlandia.data import ingest, published
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="map_3.json: file is missing"):
        published.read_reference_map(tmp_path / "map_3.json")


@pytest.mark.slow  # the published data (flat_root)
def test_truncated_json(tmp_path, flat_root):
    src = (flat_root / "individual_reference_maps/map_12.json").read_text()
    p = tmp_path / "map_12.json"
    p.write_text(src[: len(src) // 2])
    with pytest.raises(InputError, match=r"map_12.json: invalid JSON"):
        published.read_reference_map(p)


def test_invalid_json_and_wrong_shape(tmp_path):
    p = tmp_path / "local_maps.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match="local_maps.json: invalid JSON"):
        published.read_local_maps(p, "0")
    p.write_text(json.dumps([1, 2, 3]))
    with pytest.raises(InputError, match="local_maps.json: expected"):
        published.read_local_maps(p, "0")


@pytest.mark.slow  # the published data (flat_root)
def test_unknown_scene(tmp_path, flat_root):
    with pytest.raises(InputError, match="unknown scene id '42'"):
        published.read_local_maps(flat_root / "local_maps.json", "42")


def test_local_map_with_too_few_objects(tmp_path):
    p = tmp_path / "local_maps.json"
    p.write_text(json.dumps({"0": {"123": {"GT": [[1, 0], [2, 0]], "depth": [[1, 0], [2, 0]]}}}))
    with pytest.raises(InputError, match="query 123: local map has 2 object"):
        published.read_local_maps(p, "0")


def test_reference_map_with_nan(tmp_path):
    p = tmp_path / "map_0.json"
    p.write_text(json.dumps([[[2.0, 48.0], 1], [[math.nan, 48.0], 2]]).replace("NaN", "NaN"))
    with pytest.raises(InputError, match="map_0.json: 1 object.*NaN"):
        published.read_reference_map(p)


@pytest.mark.parametrize(
    "entry", [5, [[2.0], 1], [["east", 48.0], 1], [[2.0, 48.0]], [[2.0, 48.0], 1.5], [[2.0, 48.0], True]]
)
def test_a_malformed_reference_map_entry_is_named_by_its_index(tmp_path, entry):
    p = tmp_path / "map_0.json"
    p.write_text(json.dumps([[[2.0, 48.0], 1], entry]))
    with pytest.raises(InputError, match=r"map_0.json: object 1 is .*, not \[\[lon, lat\], class_id\]"):
        published.read_reference_map(p)


def test_reference_map_with_bad_class(tmp_path):
    p = tmp_path / "map_0.json"
    p.write_text(json.dumps([[[2.0, 48.0], 1], [[2.1, 48.0], 99]]))
    with pytest.raises(InputError, match="class ids outside"):
        published.read_reference_map(p, n_classes=42)


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "t.parquet"
    bad = pd.DataFrame({"a": [object()]})  # pyarrow cannot serialise this
    with pytest.raises(Exception):  # noqa: B017 - whichever error pyarrow raises, nothing may be left behind
        files.write_parquet(bad, out)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    files.write_parquet(pd.DataFrame({"a": [1, 2]}), out, {"k": 1})
    assert files.read_parquet_metadata(out) == {"k": 1}


def _copy_scene(flat_root, dst, scene="12"):
    for rel in [
        "MANIFEST.tsv",
        "local_maps.json",
        f"individual_reference_maps/map_{scene}.json",
        f"maps/{scene}/transformations.json",
        f"maps/{scene}/tokens.txt",
    ]:
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        (dst / rel).write_bytes((flat_root / rel).read_bytes())


@pytest.mark.slow  # the published data (flat_root)
def test_ingest_reports_availability(flat_root):
    rep = ingest.ingest_scene(flat_root, "12")
    assert rep["n_queries"] == 3
    assert all(rep["available"].values())  # scene 12 is complete
    rep3 = ingest.ingest_scene(flat_root, "3", verify_hash=False)
    assert rep3["available"]["reference_map"] and not rep3["available"]["sfm_points3D"]


@pytest.mark.slow  # the published data (flat_root)
def test_ingest_detects_truncation_and_missing_required(tmp_path, flat_root):
    _copy_scene(flat_root, tmp_path)
    tok = tmp_path / "maps/12/tokens.txt"
    tok.write_bytes(tok.read_bytes()[:-10])
    rep = ingest.ingest_scene(tmp_path, "12")
    rec = next(f for f in rep["files"] if f["key"] == "tokens")
    assert rec["size_ok"] is False and "truncated" in rec["problem"]
    (tmp_path / "maps/12/transformations.json").unlink()
    with pytest.raises(InputError, match="transformations.json: required file for scene 12: missing"):
        ingest.ingest_scene(tmp_path, "12")


@pytest.mark.slow  # the published data (flat_root)
def test_ingest_sha256_mismatch(tmp_path, flat_root):
    _copy_scene(flat_root, tmp_path)
    p = tmp_path / "individual_reference_maps/map_12.json"
    data = p.read_bytes()
    p.write_bytes(data.replace(b"2.37", b"2.38", 1))  # same size, different content
    with pytest.raises(InputError, match="sha256 differs"):
        ingest.ingest_scene(tmp_path, "12")


def test_config_section_layers_files_like_configfile(tmp_path):
    base, over = tmp_path / "a.yaml", tmp_path / "b.yaml"
    base.write_text("fine:\n  train: {epochs: 300, lr: 0.002}\n  coarse_strategy: 2N_LM\ncoarse: {x: 1}\n")
    over.write_text("fine:\n  train: {epochs: 1000}\n")
    got = config.config_section([base, tmp_path / "missing.yaml", over], "fine")
    assert got == {"train": {"epochs": 1000, "lr": 0.002}, "coarse_strategy": "2N_LM"}
    assert config.config_section([over], "coarse") == {}


def test_written_files_take_the_umask_mode(tmp_path):
    """Temporary files are created 0600; the renamed result gets the mode of any new file."""
    old = os.umask(0o022)
    try:
        files.write_parquet(pd.DataFrame({"a": [1]}), tmp_path / "t.parquet")
        files.write_json({"a": 1}, tmp_path / "t.json")
    finally:
        os.umask(old)
    assert {oct(p.stat().st_mode & 0o777) for p in tmp_path.iterdir()} == {oct(0o644)}
