"""The audit trail: records with the settings a rule reads, stored configs, lineage and re-hashing,
and the notice before a run redoes results built with other settings."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from conftest import REPO
from snakemake_runner import smk

from flatlandia.plumbing import provenance, rerun_notice

TINY = REPO / "config" / "test" / "tiny.yaml"


# ----------------------------------------------------------------------------- function level


def test_changed_keys_name_every_difference_but_the_selection():
    old = {"select": [], "solver": {"top_k": 6, "tau": 3.0}, "seed": 0}
    new = {"select": ["12"], "solver": {"top_k": 8, "tau": 3.0}, "seed": 1}
    assert rerun_notice.changed_keys(old, new) == ["seed: 0 -> 1", "solver.top_k: 6 -> 8"]


def test_the_notice_counts_only_jobs_that_replace_existing_results(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("a.txt").write_text("x")
    Path("b.txt").write_text("x")
    jobs = [
        rerun_notice.PlannedJob("fine_train", ("a.txt",), params_changed=True),
        rerun_notice.PlannedJob("fine_eval", ("b.txt",), code_changed=True),
        rerun_notice.PlannedJob("fine_eval", ("new.txt",), params_changed=True),  # nothing to replace
        rerun_notice.PlannedJob("queries", ("b.txt",), reason="Updated input files: x"),  # not settings or code
    ]
    text = rerun_notice.notice(jobs, {"seed": 0}, tmp_path / "none")
    first, second = text.splitlines()[:2]
    assert "redoes 3 of 4 job(s) over results that exist here" in first and "Updated input files: x (1)" in first
    assert "2 of them were built with other" in second and "fine_train 1" in second and "fine_eval 1" in second
    assert "snakemake -d runs/<name>" in text
    only = rerun_notice.notice(jobs[2:], {"seed": 0}, tmp_path / "none")  # one line: how many, and why
    assert "\n" not in only and "redoes 1 of 2 job(s)" in only and "queries 1" in only, only
    assert rerun_notice.notice(jobs[2:3], {"seed": 0}, tmp_path / "none") is None


# ----------------------------------------------------------------------------- end to end (tiny scene)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    wd = tmp_path_factory.mktemp("tiny_audit")
    res = smk(REPO, wd, "--cores", "2", "maps", "--configfile", str(TINY))
    assert res.returncode == 0, res.stderr[-3000:]
    return wd


@pytest.mark.slow  # Snakemake jobs
def test_a_record_holds_the_settings_the_rule_reads_and_the_whole_config_once(tiny_run):
    rec = json.loads((tiny_run / "logs/provenance/recover/scene-0.json").read_text())
    assert rec["settings"]["recover.tol_m"] == 0.10 and rec["config_hash"] == provenance.config_hash(rec["settings"])
    stored = provenance.stored_config(rec["config_id"], tiny_run / "logs/provenance/configs")
    assert stored["recover"]["tol_m"] == 0.10 and stored["scenes"] == "config/test/tiny_scenes.tsv"
    assert rec["workflow"]["commit"] and isinstance(rec["workflow"]["dirty"], bool)
    assert rec["scene_sheet"]["sha256"] and rec["software"]["pandas"] and rec["cpu_seconds"] > 0
    assert set(rec["inputs"]) and all(len(d) == 64 for d in rec["inputs"].values())


@pytest.mark.slow  # Snakemake jobs
def test_audit_of_an_artifact_shows_its_inputs_their_rules_and_the_settings(tiny_run):
    res = smk_cli(tiny_run, "audit", "results/0/queries/queries.parquet")
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "rule: queries" in out and "results/0/queries/recovered.parquet" in out and "recover" in out
    assert "seed: 0" in out  # a setting the rule reads, by value
    tree = smk_cli(tiny_run, "audit", "results/0/queries/queries.parquet", "--tree").stdout
    assert "local_maps.json" in tree and "(source)" in tree  # back to the published files


@pytest.mark.slow  # Snakemake jobs
def test_audit_check_names_a_file_edited_after_the_run(tiny_run):
    assert smk_cli(tiny_run, "audit", "--check").returncode == 0
    target = tiny_run / "results/0/maps/reference_map.geojson"
    original = target.read_bytes()
    try:
        target.write_bytes(original.replace(b"Feature", b"Featur3", 1))
        res = smk_cli(tiny_run, "audit", "--check")
        assert res.returncode == 1 and "results/0/maps/reference_map.geojson" in res.stdout
        one = smk_cli(tiny_run, "audit", "results/0/maps/reference_map.geojson", "--check")
        assert one.returncode == 1 and "results/0/maps/reference_map.geojson" in one.stdout
        other = smk_cli(tiny_run, "audit", "results/0/queries/queries.parquet", "--check")  # only that one
        assert other.returncode == 0 and other.stdout.strip() == "results/0/queries/queries.parquet matches its record"
        unknown = smk_cli(tiny_run, "audit", "results/0/nothing.parquet", "--check")
        assert unknown.returncode == 1 and unknown.stderr.startswith(
            "ERROR: results/0/nothing.parquet: no audit record"
        )
    finally:
        target.write_bytes(original)


@pytest.mark.slow  # Snakemake jobs
def test_the_same_artifact_from_a_selection_carries_the_same_settings_hash(tiny_run, tmp_path):
    res = smk(REPO, tmp_path, "--cores", "1", "maps", "--configfile", str(TINY), "--config", "select=[0]")
    assert res.returncode == 0, res.stderr[-2000:]
    a = json.loads((tiny_run / "logs/provenance/reference_map/scene-0.json").read_text())
    b = json.loads((tmp_path / "logs/provenance/reference_map/scene-0.json").read_text())
    assert a["config_hash"] == b["config_hash"] and a["config_id"] != b["config_id"]


@pytest.mark.slow  # Snakemake jobs
def test_a_changed_setting_is_announced_before_the_first_job(tiny_run):
    res = smk(REPO, tiny_run, "--cores", "1", "maps", "--configfile", str(TINY), "--config", "recover={tol_m: 0.09}")
    assert res.returncode == 0, res.stderr[-2000:]
    err = res.stderr
    assert "flatlandia: this run redoes" in err and "recover 1" in err, err[-3000:]
    assert "recover.tol_m: 0.1 -> 0.09" in err and "snakemake -d runs/<name>" in err
    # the notice comes before Snakemake starts the first job
    assert err.index("flatlandia: this run redoes") < err.index("rule recover")
    man = (
        pd.read_parquet(tiny_run / "results/manifest.parquet")
        if (tiny_run / "results/manifest.parquet").exists()
        else None
    )
    assert man is None or "settings" in man.columns


def smk_cli(wd: Path, *args: str):
    import subprocess
    import sys

    exe = str(Path(sys.executable).parent / "flatlandia")
    return subprocess.run([exe, *args], cwd=wd, capture_output=True, text=True, timeout=300)


# ----------------------------------------------------------------------------- users' files, optional columns


def test_a_scene_sheet_with_only_its_required_columns_plans_the_maps(tmp_path):
    """scene, source, city: the optional columns (name, path, url, subfolder, sha256) may be absent."""
    from conftest import smk_dry_run

    sheet = tmp_path / "scenes.tsv"
    sheet.write_text("scene\tsource\tcity\n0\tflatlandia\tTinytown\n")
    res = smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", f"scenes={sheet}")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "reference_map" in res.stdout and "queries" in res.stdout


def test_a_misspelt_selection_is_one_error_line_before_any_traceback(tmp_path):
    from conftest import smk_dry_run

    res = smk_dry_run(REPO, tmp_path, "maps", "--configfile", str(TINY), "--config", "select=[Tinytwn]")
    assert res.returncode != 0 and "Traceback" not in res.stderr and 'File "' not in res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("ERROR:")]
    assert errors == [errors[0]] and "unknown scene id(s) or city(ies) ['Tinytwn']" in errors[0], res.stderr[-2000:]
