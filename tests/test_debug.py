"""flatlandia.plumbing.debug: a rule's script run outside Snakemake gets the job Snakemake would run."""

from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest
from snakemake_runner import smk

from flatlandia import cli
from flatlandia.plumbing import debug, files


@pytest.mark.slow  # the published data (flat_root)
def test_mock_snakemake_resolves_the_job(repo, flat_root, tmp_path):
    s = debug.mock_snakemake("reference_map", workdir=tmp_path, config={"flatlandia_root": str(flat_root)}, scene=12)
    assert s.rule == "reference_map" and s.wildcards.scene == "12"
    assert s.input.reference_map == str(flat_root / "individual_reference_maps/map_12.json")
    assert s.output.parquet == "results/12/maps/reference_map.parquet"
    assert list(s.log) == ["logs/reference_map/12.log"]
    assert s.params.source == "flatlandia" and s.threads == 1
    assert s.config["flatlandia_root"] == str(flat_root) and s.config["seed"] == 0  # default config
    assert s.script == repo / "workflow/scripts/reference_map.py"
    # a config file over the default, as --configfile: paper.yaml changes the training epochs
    paper = debug.mock_snakemake("coarse_train", workdir=tmp_path, configfiles=[repo / "config/paper.yaml"], loss="sim")
    assert paper.params["coarse.train"]["epochs"] == 800 and paper.output.model == "results/coarse/sim/model.pt"


def test_mock_snakemake_names_what_is_wrong(tmp_path):
    with pytest.raises(debug.DebugError, match="no rule 'nope'"):
        debug.mock_snakemake("nope", workdir=tmp_path)
    with pytest.raises(debug.DebugError, match=r"missing \['scene'\]"):
        debug.mock_snakemake("reference_map", workdir=tmp_path)
    with pytest.raises(debug.DebugError, match=r"unknown \['city'\]"):
        debug.mock_snakemake("reference_map", workdir=tmp_path, scene=12, city="Paris")
    s = debug.mock_snakemake("reference_map", workdir=tmp_path, scene=12)
    with pytest.raises(debug.DebugError, match="missing input"):
        debug.run_script(s)


@pytest.mark.slow  # the published data (flat_root)
def test_script_run_outside_snakemake_writes_what_the_workflow_writes(repo, flat_root, tmp_path, capsys):
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        "results/12/maps/reference_map.parquet",
        "--config",
        f"flatlandia_root={flat_root}",
    )
    assert res.returncode == 0, res.stderr[-2000:]
    made = tmp_path / "workflow_made"
    shutil.copytree(tmp_path / "results/12/maps", made)
    shutil.rmtree(tmp_path / "results/12/maps")
    s = debug.mock_snakemake("reference_map", workdir=tmp_path, config={"flatlandia_root": str(flat_root)}, scene=12)
    debug.run_script(s)
    ours = tmp_path / "results/12/maps"
    pd.testing.assert_frame_equal(
        pd.read_parquet(ours / "reference_map.parquet"), pd.read_parquet(made / "reference_map.parquet")
    )
    assert files.read_parquet_metadata(ours / "reference_map.parquet") == files.read_parquet_metadata(
        made / "reference_map.parquet"
    )
    assert json.loads((ours / "reference_map.geojson").read_text()) == json.loads(
        (made / "reference_map.geojson").read_text()
    )
    assert "scene 12:" in (tmp_path / "logs/reference_map/12.log").read_text()
    # the command line: prints the job, runs it, logs to the terminal when asked
    shutil.rmtree(ours)
    rc = cli.main(
        ["debug", "reference_map", "scene=12", "-d", str(tmp_path), "--config", f"flatlandia_root={flat_root}"]
        + ["--log-to-terminal"]
    )
    out = capsys.readouterr()
    assert rc == 0, out
    assert "output:\n    parquet: 'results/12/maps/reference_map.parquet'" in out.out
    assert "scene 12:" in out.err and "done; outputs:" in out.out
    pd.testing.assert_frame_equal(
        pd.read_parquet(ours / "reference_map.parquet"), pd.read_parquet(made / "reference_map.parquet")
    )
    assert cli.main(["debug", "reference_map", "scene=12", "-d", str(tmp_path), "--show"]) == 0
    assert cli.main(["debug", "reference_map", "12", "-d", str(tmp_path)]) == 2
