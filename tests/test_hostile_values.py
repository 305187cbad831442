"""Untrusted inputs, second pass: names that would become paths outside the run, config values
that passed the schema and ended in tracebacks, PLY headers that declare more than the file holds,
checkpoints whose weights do not fit their model. Every case ends in one ``ERROR:`` line (or an
:class:`InputError` naming the file) and writes nothing outside the run folder.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from snakemake_runner import smk

from flatlandia import checkpoints, config
from flatlandia.data import ingest
from flatlandia.fine import models
from flatlandia.objects import cloud
from flatlandia.plumbing import names, ply, rule_log
from flatlandia.plumbing.errors import InputError

HOSTILE_NAMES = ["../../x", "/x", "a/b", "..", ".", "", " ", "x\\..\\y", "x\ny", "x" * 300]


def tree(root: Path) -> set[str]:
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        out |= {str(Path(dirpath, n).relative_to(root)) for n in dirnames + filenames}
    return out


# ----------------------------------------------------------------------------- names -> paths


@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_a_name_that_is_not_one_plain_component_is_refused(tmp_path, name):
    with pytest.raises(InputError, match=r"query token .* is refused"):
        names.child(tmp_path, name, ".png", "query token")
    assert names.child(tmp_path, "1234_abc-5.jpg", ".png") == tmp_path / "1234_abc-5.jpg.png"
    assert names.child(tmp_path, "-AB21Af_LPev08UY_96ptQ") == tmp_path / "-AB21Af_LPev08UY_96ptQ"  # a published token


@pytest.mark.parametrize("token", ["../../x", "/x", "a/b"])
def test_a_published_token_that_is_a_path_is_refused_when_read(tmp_path, token):
    path = tmp_path / "local_maps.json"
    local = [[1.0, 0.0], [2.0, 1.0], [3.0, -1.0]]
    path.write_text(json.dumps({"0": {"123": {"GT": local, "depth": local}, token: {"GT": local, "depth": local}}}))
    with pytest.raises(InputError, match=r"local_maps.json: scene 0 query token .* is refused"):
        from flatlandia.data import published

        published.read_local_maps(path, "0")


@pytest.mark.slow  # the published data (all_local_maps)
def test_every_published_token_is_a_plain_name(flat_root, all_local_maps):
    """The check refuses paths, not the data: Mapillary ids such as '-AB21Af_LPev08UY_96ptQ' pass."""
    tokens = [t for scene in all_local_maps.values() for t in scene]
    tokens += [t for f in flat_root.glob("maps/*/tokens.txt") for t in f.read_text().split()]
    assert len(tokens) > 2000 and any(t.startswith("-") for t in tokens)
    assert [t for t in tokens if names.name_problem(t)] == []


@pytest.mark.slow  # the published data (flat_root)
def test_a_tokens_file_with_a_path_is_refused_by_ingest(tmp_path, flat_root):
    for rel in ["local_maps.json", "individual_reference_maps/map_12.json", "maps/12/transformations.json"]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(flat_root / rel, tmp_path / rel)
    (tmp_path / "maps/12/tokens.txt").write_text("123\n../../../etc/x\n")
    rep = ingest.ingest_scene(tmp_path, "12", verify_hash=False)
    rec = next(f for f in rep["files"] if f["key"] == "tokens")
    assert rec["parse_ok"] is False and "query token '../../../etc/x' is refused" in rec["problem"]


def _data_with_token(flat_root: Path, data: Path, token: str) -> None:
    """A copy of the published data (no clouds, no SfM, no manifest: an edited download) whose
    scene 12 holds one more query, named ``token``, a copy of an existing one."""
    shutil.copytree(flat_root, data, ignore=shutil.ignore_patterns("*.ply", "*.bin", "*.zip", "MANIFEST.tsv"))
    for p in data.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    local = json.loads((data / "local_maps.json").read_text())
    first = next(iter(local["12"].values()))
    local["12"][token] = first
    (data / "local_maps.json").write_text(json.dumps(local))


@pytest.mark.slow  # the published data (flat_root)
def test_a_hostile_token_stops_the_workflow_and_writes_nothing_outside(repo, flat_root, tmp_path):
    """The probe's token ``../../x`` wrote a PNG outside the run folder, rc 0: now the first rule
    that reads it stops with one ERROR line naming the file, and nothing appears outside."""
    data, wd = tmp_path / "data", tmp_path / "run" / "wd"
    _data_with_token(flat_root, data, "../../x")
    wd.mkdir(parents=True)
    before = tree(tmp_path) - {p for p in tree(tmp_path) if p.startswith("run")}
    res = smk(repo, wd, "--cores", "1", "results/12/queries/queries.parquet", "--config", f"flatlandia_root={data}")
    assert res.returncode != 0
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("ERROR:")]
    assert errors and all("local_maps.json: scene 12 query token '../../x' is refused" in e for e in errors), errors
    assert "Traceback" not in res.stderr
    after = tree(tmp_path) - {p for p in tree(tmp_path) if p.startswith("run/wd") or p == "run"}
    assert after == before, after - before
    assert not (wd / "results/12/queries/queries.parquet").exists()


# ----------------------------------------------------------------------------- config values


@pytest.mark.parametrize(
    ("cfg", "message"),
    [
        ({"recover": {"tol_m": float("nan")}}, "'recover.tol_m': nan is not a finite number"),
        ({"fetch": {"max_download_mb": float("nan")}}, "'fetch.max_download_mb': nan is not a finite number"),
        ({"fetch": {"max_download_mb": float("inf")}}, "'fetch.max_download_mb': inf is not a finite number"),
        ({"objects": {"cluster": {"eps_m": float("nan")}}}, "'objects.cluster.eps_m': nan is not a finite number"),
        ({"fine": {"train": {"seed": 4294967296}}}, "'fine.train.seed': 4294967296 is greater than the maximum"),
        ({"seed": -1}, "'seed': -1 is less than the minimum"),
        ({"seed": 10**12}, "'seed': 1000000000000 is greater than the maximum"),
        ({"split": {"train": 0.8, "val": 0.3}}, "'split': train \\+ val \\+ test must sum to 1, not 1.2"),
    ],
)
def test_a_value_the_schema_let_through_is_refused(cfg, message):
    with pytest.raises(config.ConfigError, match=message):
        config.resolve(cfg)


def test_every_seed_of_the_schema_is_bounded():
    """Seeds feed numpy and torch, which refuse values past 2**32 deep inside a job: each seed key
    has a maximum that leaves room for the offsets added to it."""

    def seeds(node, prefix=""):
        for key, child in node.get("properties", {}).items():
            name = f"{prefix}.{key}" if prefix else key
            if "seed" in key and child.get("type") == "integer":
                yield name, child
            yield from seeds(child, name)

    found = dict(seeds(config.schema()))
    assert "seed" in found and "fine.train.seed" in found
    for name, node in found.items():
        assert node.get("minimum") == 0 and node.get("maximum", 2**40) <= 10**9, name
    # the coarse models' seed is the master seed plus an offset: still a positive int32 (pycolmap, numpy)
    assert found["seed"]["maximum"] + found["coarse.seed_offset"]["maximum"] < 2**31


@pytest.mark.slow  # the published data (flat_root)
def test_a_nan_in_a_config_file_stops_the_run_before_any_job(repo, flat_root, tmp_path):
    cfg = tmp_path / "mine.yaml"
    cfg.write_text("recover:\n  tol_m: .nan\nsplit: {train: 0.5}\n")
    res = smk(repo, tmp_path, "-n", "maps", "--configfile", str(cfg), "--config", f"flatlandia_root={flat_root}")
    assert res.returncode != 0
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("ERROR:")]
    assert len(errors) == 1 and "'recover.tol_m': nan is not a finite number" in errors[0], errors
    assert "Traceback" not in res.stderr


# ----------------------------------------------------------------------------- PLY headers


def _ply(path: Path, n_declared: int, n_written: int, fmt: str = "binary_little_endian") -> Path:
    header = (
        f"ply\nformat {fmt} 1.0\nelement vertex {n_declared}\n"
        "property double x\nproperty double y\nproperty double z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    if fmt == "ascii":
        body = "".join("1 2 3 51 51 51\n" for _ in range(n_written)).encode()
    else:
        row = np.zeros(1, dtype=[("xyz", "<f8", 3), ("rgb", "u1", 3)])
        row["rgb"] = 51
        body = np.repeat(row, n_written).tobytes()
    path.write_bytes(header.encode() + body)
    return path


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_a_ply_header_declaring_more_than_the_file_holds_is_refused(tmp_path, fmt):
    bad = _ply(tmp_path / "cloud.ply", 4_000_000_000, 10, fmt)
    with pytest.raises(InputError, match=r"cloud.ply: PLY header declares 4000000000 .*(truncated or forged)"):
        cloud.read_classified_cloud(bad)
    good = _ply(tmp_path / "good.ply", 10, 10, fmt)
    pts, labels = cloud.read_classified_cloud(good)
    assert pts.shape == (10, 3) and set(labels) == {cloud.BACKGROUND}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("ply\nformat binary_little_endian 1.0\nelement vertex -5\nend_header\n", "malformed PLY header, line 3"),
        ("ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty quad x\nend_header\n", "line 4"),
        ("ply\nformat zip 1.0\nelement vertex 0\nend_header\n", "PLY format 'zip'"),
        ("not a ply\n", "not a PLY file"),
        ("ply\nformat ascii 1.0\n" + "comment x\n" * 10000, "no end_header"),
    ],
)
def test_malformed_ply_headers_are_refused(tmp_path, text, message):
    path = tmp_path / "x.ply"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        ply.check_header(path)


@pytest.mark.slow  # the published data (flat_root)
def test_every_published_ply_passes_the_header_check(flat_root):
    plys = sorted(flat_root.glob("maps/*/*.ply"))
    assert len(plys) >= 20
    for p in plys:
        header = ply.check_header(p)
        assert header.count("vertex") > 0, p


# ----------------------------------------------------------------------------- checkpoints


def _checkpoint(tmp_path: Path, state_dict: dict, **cfg_over) -> Path:
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    cfg_dict = {**cfg.to_dict(), **cfg_over}
    path = tmp_path / "ck.pt"
    torch.save({"format": checkpoints.FORMAT, "state_dict": state_dict, "meta": json.dumps({"config": cfg_dict})}, path)
    return path


@pytest.mark.parametrize("case", ["shape", "missing", "extra", "not_tensors", "bad_config"])
def test_a_checkpoint_whose_weights_do_not_fit_is_one_error(tmp_path, capsys, case):
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    state = models.build_model(cfg).state_dict()
    key = next(iter(state))
    over = {}
    if case == "shape":
        state[key] = torch.zeros(3, 3)
    elif case == "missing":
        state.pop(key)
    elif case == "extra":
        state["intruder.weight"] = torch.zeros(1)
    elif case == "not_tensors":
        state[key] = [1, 2, 3]
    else:
        over = {"hiddenn": 8}
    path = _checkpoint(tmp_path, state, **over)

    def main(smk, log):  # as a rule script loads it
        checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)

    with pytest.raises(SystemExit):
        rule_log.run(main, SimpleNamespace(log=[]))
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and errors[0].startswith(f"ERROR: {path}: "), err
    assert "delete it and rerun" in errors[0] and "Traceback" not in err
