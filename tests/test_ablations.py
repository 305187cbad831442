"""The `ablations` target: rows that are not the benchmark's headline (the solver without the
training split's camera prior, on the whole map and in the sequence and fix protocol) leave `all`
for a table of their own, results/tables/ablations.{md,parquet}."""

from __future__ import annotations

import pandas as pd
import pytest
from conftest import REPO, smk_dry_run
from snakemake_runner import job_stats, smk

from flatlandia import paths, vocabulary

TINY = ("--configfile", str(REPO / "config" / "test" / "tiny.yaml"))
NOPRIOR = paths.fine_run("solver-noprior", "depth", "whole")
PRIOR_OFF = paths.beyond_scene("off")


def test_all_plans_no_ablation_and_the_ablations_target_plans_them(tmp_path):
    (tmp_path / "all").mkdir()
    (tmp_path / "ablations").mkdir()
    every = smk_dry_run(REPO, tmp_path / "all", "all", *TINY)
    assert every.returncode == 0, every.stderr[-3000:]
    assert NOPRIOR not in every.stdout and PRIOR_OFF not in every.stdout
    assert "ablations_table" not in job_stats(every.stdout)
    ablations = smk_dry_run(REPO, tmp_path / "ablations", "ablations", *TINY)
    assert ablations.returncode == 0, ablations.stderr[-3000:]
    planned = job_stats(ablations.stdout)
    assert planned["ablations_table"] == 1 and planned["beyond_scene"] == 2  # camera prior on and off
    assert NOPRIOR in ablations.stdout and PRIOR_OFF in ablations.stdout
    assert paths.fine_run("solver", "depth", "whole") in ablations.stdout  # the run it ablates, beside it


def test_an_ablation_run_names_the_run_it_ablates():
    assert vocabulary.ablated_run("solver-noprior_depth_whole") == "solver_depth_whole"
    assert vocabulary.ablated_run("solver-noprior_gt_gtbb") == "solver_gt_gtbb"
    assert vocabulary.ablated_run("mlp_depth_whole") is None


@pytest.mark.slow  # runs Snakemake jobs (the tiny scene)
def test_the_ablations_table_puts_each_ablation_beside_its_run(tmp_path):
    res = smk(REPO, tmp_path, "--cores", "2", "ablations", *TINY)
    assert res.returncode == 0, res.stderr[-4000:]
    fine = pd.read_parquet(tmp_path / paths.table("ablations"))
    assert list(fine["run"]) == ["solver_depth_whole", "solver-noprior_depth_whole"]
    rows = pd.read_parquet(tmp_path / paths.table("ablations_one_frame"))
    assert set(rows["camera_prior"]) == {"on", "off"}
    md = (tmp_path / paths.table("ablations", "md")).read_text()
    assert md.startswith("# Ablations\n") and "\n## " in md and "\n# " not in md[1:]
    assert "geometric solver, no camera prior" in md
