"""End-to-end: the Snakemake workflow on real scenes, dry runs, lint and bad input."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd
import pytest
from snakemake_runner import job_stats, smk

from flatlandia.plumbing import files

#: every test here runs Snakemake jobs or reads the published data (the slow lane)
pytestmark = pytest.mark.slow

TEST_CONFIGS = Path(__file__).resolve().parents[1] / "config" / "test"


def two_scenes(flat_root, *more: str, select: str | None = None) -> list[str]:
    """Arguments of the two-scene runs: config/test/two_scenes.yaml (scenes 9 and 12 are both the
    selection and the benchmark), then the files of config/test named in ``more``; on the command
    line the data folder, and another selection when given."""
    configs = [str(TEST_CONFIGS / name) for name in ("two_scenes.yaml", *more)]
    settings = [f"flatlandia_root={flat_root}", *([f"select={select}"] if select else [])]
    return ["--configfile", *configs, "--config", *settings]


@pytest.fixture(scope="module")
def run_two_scenes(repo, flat_root, tmp_path_factory):
    wd = tmp_path_factory.mktemp("e2e")
    res = smk(
        repo,
        wd,
        "--cores",
        "2",
        "all",
        *two_scenes(flat_root),
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return wd


@pytest.mark.slow
def test_end_to_end_two_scenes(run_two_scenes, flat_root):
    wd = run_two_scenes
    for scene, n_q, n_obj in (("9", 12, 13), ("12", 3, 44)):
        q = pd.read_parquet(wd / f"results/{scene}/queries/queries.parquet")
        assert len(q) == n_q and (q["residual_m"] < 0.01).all()
        ref = pd.read_parquet(wd / f"results/{scene}/maps/reference_map.parquet")
        assert len(ref) == n_obj and {"x_m", "y_m", "lon", "lat", "class_id", "class_label"} <= set(ref.columns)
        meta = files.read_parquet_metadata(wd / f"results/{scene}/maps/reference_map.parquet")
        assert "+proj=tmerc" in meta["crs"]
        gj = json.loads((wd / f"results/{scene}/maps/reference_map.geojson").read_text())
        assert gj["type"] == "FeatureCollection" and len(gj["features"]) == n_obj
        lon, lat = gj["features"][0]["geometry"]["coordinates"]
        assert (lon, lat) == pytest.approx((ref["lon"][0], ref["lat"][0]))
        png = wd / f"results/{scene}/maps/reference_map.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (wd / f"logs/recover/{scene}.log").read_text().count("queries recovered") == 1
        assert (wd / f"logs/benchmarks/recover/{scene}.tsv").exists()
    for t, flat in (
        ("dataset_stats", "dataset_stats"),
        ("recovery", "recovery"),  # one line per Parquet row
        ("reference_map_reproduction", "reference_map_reproduction"),
        ("coarse_localization", "coarse_localization_rows"),
        ("fine_localization", "fine_localization_rows"),
    ):
        md = [ln for ln in (wd / f"results/tables/{flat}.md").read_text().splitlines() if ln.startswith("| ")]
        assert len(md) == 1 + len(pd.read_parquet(wd / f"results/tables/{t}.parquet"))
        assert (wd / f"results/tables/{t}.tex").read_text().startswith("\\begin{table}")
    stats = pd.read_parquet(wd / "results/tables/dataset_stats.parquet")
    assert list(stats["city"]) == ["Lisbon", "Paris", "all"]
    assert stats.set_index("city").loc["all", "total_queries"] == 15
    fine = pd.read_parquet(wd / "results/tables/fine_localization.parquet").set_index("run")
    assert fine.loc["solver_gt_gtbb", "median_m"] < 1e-6  # GT local maps are exact rigid copies
    assert fine.loc["solver_depth_gtbb", "queries"] == fine.loc["solver_gt_gtbb", "queries"] > 0
    assert {"mlp_depth_gtbb", "solver_depth_coarse-simtrip", "solver_depth_whole", "gat_att_depth_gtbb"} <= set(
        fine.index
    )
    assert fine.loc["mlp_depth_gtbb", "trained_on"] == "GT-BB" and fine.loc["solver_depth_gtbb", "trained_on"] == ""
    assert fine.loc["mlp_depth_coarse-simtrip", "trained_on"] == "simulated coarse, cut to 30 m"
    assert (wd / "results/fine/models/mlp_depth_coarse/checkpoint.pt").exists()
    coarse = pd.read_parquet(wd / "results/tables/coarse_localization.parquet")
    assert len(coarse) > 0 and coarse["success"].between(0, 1).all()
    solver_rows = coarse[coarse["loss"] == "Solver"].set_index(["map_type", "strategy"])
    assert {"N_LM", "2N_LM", "R_30", "BB"} <= set(solver_rows.index.get_level_values("strategy"))
    assert solver_rows.loc[("gt", "N_LM"), "precision"] > 0.9  # GT maps: the solver's matches are the true ones
    assert fine.loc["mlp_depth_coarse-solver", "trained_on"] == "GT-BB"  # the box feeds the GT-BB-trained model
    avail = pd.read_parquet(wd / "results/tables/availability.parquet").set_index("scene")
    assert avail.loc["12"].drop("queries").all() and not avail.loc["9", "sfm_images"]
    rec = pd.read_parquet(wd / "results/tables/recovery.parquet")
    assert rec.set_index("scene").loc["all", "recovered"] == 15


@pytest.mark.slow
def test_city_target_tiles_the_benchmark_scenes_and_writes_the_table(run_two_scenes, repo, flat_root):
    """`snakemake city` on the two-scene benchmark: cities of 1 and 2 scenes, a small simulated one;
    the table has both methods at each tiled size, every test query localized at every size."""
    res = smk(repo, run_two_scenes, "--cores", "2", "city", *two_scenes(flat_root, "city_small.yaml"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    df = pd.read_parquet(run_two_scenes / "results/tables/city_scale.parquet")
    tiled = df[df["map"] == "tiled"].set_index(["scenes", "method"])
    assert set(tiled.index) == {(n, m) for n in (1, 2) for m in ("whole-map solver", "index + solver")}
    assert (tiled["queries"] == tiled["queries"].iloc[0]).all() and tiled["queries"].iloc[0] > 0
    assert tiled.loc[(2, "whole-map solver"), "objects"] == 13 + 44  # scenes 9 and 12 in one map
    assert (df[df["map"] == "simulated"]["objects"] >= 150).all()
    assert "City scale" in (run_two_scenes / "results/tables/city_scale.md").read_text()
    # beyond one frame: the city rows in a table of their own, beside the scene rows of `all`'s
    beyond = pd.read_parquet(run_two_scenes / "results/tables/beyond_one_frame_city.parquet")
    assert set(beyond["map"]) == {"scene", "city-2", "simulated-150"}
    assert set(pd.read_parquet(run_two_scenes / "results/tables/beyond_one_frame.parquet")["map"]) == {"scene"}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_manifest_and_audit_trace_every_artifact(run_two_scenes):
    wd = run_two_scenes
    man = pd.read_parquet(wd / "results/manifest.parquet").set_index("artifact")
    q = "results/12/queries/queries.parquet"
    assert man.loc[q, "rule"] == "queries" and man.loc[q, "scene"] == "12"
    assert man.loc[q, "sha256"] == files.sha256(wd / q)
    inputs = json.loads(man.loc[q, "inputs"])
    assert inputs["results/12/queries/recovered.parquet"] == files.sha256(wd / "results/12/queries/recovered.parquet")
    assert man["git_commit"].str.len().min() >= 7 and man["config_id"].nunique() == 1  # one resolved config
    # the settings hash covers what each rule reads: the queries of both scenes share theirs, rules differ
    assert man.loc["results/9/queries/queries.parquet", "config_hash"] == man.loc[q, "config_hash"]
    assert man.loc[q, "config_hash"] != man.loc["results/12/maps/reference_map.png", "config_hash"]
    assert json.loads(man.loc[q, "settings"])["seed"] == 0
    assert {"ingest", "recover", "reference_map", "plot_reference_map", "dataset_stats"} <= set(man["rule"])
    res = subprocess.run(
        [str(Path(sys.executable).parent / "flatlandia"), "audit", "--scene", "12"],
        cwd=wd,
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0 and q in res.stdout and "results/9/" not in res.stdout
    res = subprocess.run(
        [str(Path(sys.executable).parent / "flatlandia"), "audit", "--scene", "99"],
        cwd=wd,
        capture_output=True,
        text=True,
    )
    assert (
        res.returncode == 1
        and res.stdout == ""
        and res.stderr.startswith("ERROR: no audit records for scene '99'; scenes with records: ")
    )
    assert {oct((wd / q).stat().st_mode & 0o777), oct((wd / "results/manifest.parquet").stat().st_mode & 0o777)} == {
        oct(0o666 & ~_umask())
    }


@pytest.mark.slow
def test_rerun_is_a_no_op(run_two_scenes, repo, flat_root):
    res = smk(
        repo,
        run_two_scenes,
        "-n",
        "all",
        *two_scenes(flat_root),
    )
    assert res.returncode == 0
    assert "Nothing to be done" in res.stdout + res.stderr
    # selecting one scene afterwards touches neither the models nor the tables of the benchmark
    res = smk(
        repo,
        run_two_scenes,
        "-n",
        "all",
        *two_scenes(flat_root, select="[12]"),
    )
    assert res.returncode == 0 and "Nothing to be done" in res.stdout + res.stderr
    shared = ["results/tables", "results/fine", "results/coarse"]
    before = {
        p: hashlib.sha256(p.read_bytes()).hexdigest()
        for d in shared
        for p in (run_two_scenes / d).rglob("*")
        if p.is_file()
    }
    res = smk(repo, run_two_scenes, "--cores", "2", "all", *two_scenes(flat_root, select="[12]"))
    assert res.returncode == 0, res.stderr[-2000:]
    after = {
        p: hashlib.sha256(p.read_bytes()).hexdigest()
        for d in shared
        for p in (run_two_scenes / d).rglob("*")
        if p.is_file()
    }
    assert len(before) > 20 and after == before
    # a benchmark on another scene set is a named run of its own folder, never an overwrite here
    args = ["--config", "benchmark_scenes=[12]", f"flatlandia_root={flat_root}"]
    res = smk(repo, run_two_scenes, "-n", "all", *args)
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    assert res.returncode != 0 and len(errors) == 1 and "snakemake -d runs/<name>" in errors[0], res.stderr[-2000:]
    assert "['12']" in errors[0] and "['12', '9']" in errors[0]
    subset = run_two_scenes / "runs" / "subset"
    subset.mkdir(parents=True, exist_ok=True)
    res = smk(repo, subset, "-n", "benchmark", *args)
    assert res.returncode == 0 and "rule fine_train:" in res.stdout, res.stderr[-2000:]


@pytest.mark.slow
def test_report_holds_every_figure(run_two_scenes, repo, flat_root):
    wd = run_two_scenes
    res = smk(
        repo,
        wd,
        "--report",
        "results/report.zip",
        *two_scenes(flat_root),
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    names = "\n".join(zipfile.ZipFile(wd / "results/report.zip").namelist())
    for figure in (
        "reference_map.png",
        "training_curves.png",
        "fine_error_cdf.png",
        "fine_error_vs_objects.png",
        "coarse_scores_",
        "reference_map_reproduction.png",
    ):
        assert figure in names, figure


def test_dry_run_lists_the_full_dag(repo, flat_root, tmp_path):
    res = smk(repo, tmp_path, "-n", "all", "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    counts = {
        "ingest": 20,
        "recover": 20,
        "reference_map": 21,
        "queries": 21,
        "plot_reference_map": 21,
        "objects": 13,
        "principal_plane": 12,
        "gps_alignment": 1,
        "coarse_target": 20,
        "coarse_train": 3,
        "fine_table": 1,
        "figures_fine_errors": 1,
        "manifest": 1,
    }
    for rule, n in counts.items():  # 20 published scenes (12 with a class cloud) + the Lund images scene
        assert any(line.split()[:2] == [rule, str(n)] for line in out.splitlines()), rule


@pytest.mark.slow
def test_paper_config_merges_over_the_default(repo, flat_root, tmp_path):
    """config/paper.yaml only names what differs: the default's other keys survive the merge and
    its runs widen the DAG (5 methods x 2 map types x 5 proposals + 4 whole-map runs)."""
    res = smk(
        repo,
        tmp_path,
        "-n",
        "all",
        "--configfile",
        str(repo / "config/paper.yaml"),
        "--config",
        f"flatlandia_root={flat_root}",
    )
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    counts = {
        "fine_train": 16,
        "fine_eval": 54,
        "coarse_train": 3,
        "coarse_target": 20,
    }  # 4 models x 2 maps x 2 trainings
    for rule, n in counts.items():
        assert any(line.split()[:2] == [rule, str(n)] for line in out.splitlines()), rule
    assert "results/fine/gat_att_depth_coarse-trip/errors.parquet" in out


def test_select_a_city(repo, flat_root, tmp_path):
    res = smk(repo, tmp_path, "-n", "maps", "--config", "select=[Berlin]", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    assert "results/3/queries/queries.parquet" in out and "results/4/queries/queries.parquet" in out
    assert "results/5/queries/queries.parquet" not in out


def test_select_never_shrinks_the_benchmark(repo, flat_root, tmp_path):
    """`all` with a selection trains on the benchmark scenes (all published ones by default), not on
    the selection: the models and tables are the benchmark's whatever is selected."""
    res = smk(repo, tmp_path, "-n", "all", "--config", "select=[Berlin]", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stderr[-2000:]
    train = [b for b in res.stdout.split("\n\n") if "rule coarse_train:" in b]
    assert train and all("results/5/queries/queries.parquet" in b for b in train)


def test_unknown_selection_is_a_clear_error(repo, flat_root, tmp_path):
    res = smk(repo, tmp_path, "-n", "all", "--config", "select=[Atlantis]", f"flatlandia_root={flat_root}")
    assert res.returncode != 0
    assert "unknown scene id(s) or city(ies) ['Atlantis']" in res.stdout + res.stderr


def test_lint_is_clean(repo, tmp_path, flat_root):
    res = smk(repo, tmp_path, "--lint", "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stdout[-3000:]
    assert "Lints for" not in res.stdout, res.stdout[-3000:]


def test_bad_reference_map_stops_the_rule_without_output(repo, flat_root, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(flat_root, data, ignore=shutil.ignore_patterns("*.ply", "*.bin", "*.zip", "MANIFEST.tsv"))
    for p in data.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    bad = data / "individual_reference_maps/map_12.json"
    objs = json.loads(bad.read_text())
    objs[3][0][0] = None
    bad.write_text(json.dumps(objs))
    wd = tmp_path / "wd"
    wd.mkdir()
    res = smk(repo, wd, "--cores", "1", "results/12/maps/reference_map.parquet", "--config", f"flatlandia_root={data}")
    assert res.returncode != 0
    log = (wd / "logs/ingest/12.log").read_text()
    assert "map_12.json" in log and "object 3 is [[None," in log and "not [[lon, lat], class_id]" in log
    assert not (wd / "results/12/maps/reference_map.parquet").exists()
    assert not (wd / "results/12/ingest/ingest.json").exists()


def test_missing_data_is_fetched_or_fails_fast_offline(repo, tmp_path):
    cfg = tmp_path / "offline.yaml"
    cfg.write_text(
        f"flatlandia_root: {tmp_path / 'nowhere'}\n"
        f"fetch: {{url: 'https://127.0.0.1:9/x.zip', dest: '{tmp_path / 'resources' / 'fetched'}', timeout_s: 5}}\n"
    )  # a fetch writes only below the working folder's resources/ (docs/security.md, the write rule)
    res = smk(repo, tmp_path, "--cores", "1", "results/12/ingest/ingest.json", "--configfile", str(cfg))
    assert res.returncode != 0
    log = (tmp_path / "logs/fetch_flatlandia/fetch.log").read_text()
    assert "could not download" in log and "FLATLANDIA_ROOT" in log
    assert not (tmp_path / "resources" / "fetched").exists()


@pytest.mark.slow
def test_rerun_from_scratch_gives_identical_tables(run_two_scenes, repo, flat_root, tmp_path):
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "2",
        "all",
        *two_scenes(flat_root),
    )
    assert res.returncode == 0, res.stderr[-2000:]
    tables = [
        "results/12/queries/queries.parquet",
        "results/9/queries/queries.parquet",
        "results/12/maps/reference_map.parquet",
        "results/tables/dataset_stats.parquet",
        "results/tables/dataset_stats_per_scene.parquet",
        "results/tables/availability.parquet",
    ]
    for t in tables:
        pd.testing.assert_frame_equal(
            pd.read_parquet(run_two_scenes / t), pd.read_parquet(tmp_path / t), check_exact=True
        )
    # trained models too (CPU, seeded); wall-clock columns are the only ones allowed to differ
    for t in (
        "results/tables/recovery.parquet",
        "results/tables/coarse_localization.parquet",
        "results/tables/fine_localization.parquet",
        "results/coarse/simtrip/proposals.parquet",
        "results/fine/mlp_depth_gtbb/errors.parquet",
        "results/12/objects/objects.parquet",
        "results/tables/reference_map_reproduction.parquet",
    ):
        a, b = pd.read_parquet(run_two_scenes / t), pd.read_parquet(tmp_path / t)
        timing = [c for c in a.columns if re.search(r"(seconds|_s$|_ms$|_time)", c)]
        pd.testing.assert_frame_equal(a.drop(columns=timing), b.drop(columns=timing), check_exact=True, obj=t)


def test_maps_of_one_city_plan_no_training_and_no_shared_table(repo, flat_root, tmp_path):
    res = smk(repo, tmp_path, "-n", "maps", "--config", "select=[Paris]", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stderr[-2000:]
    planned = set(job_stats(res.stdout)) - {"total"}
    assert {"reference_map", "queries", "recover"} <= planned
    assert not planned & {"coarse_train", "fine_train", "coarse_eval", "fine_eval", "dataset_stats", "fine_table"}
    assert "results/tables/" not in res.stdout


def test_training_on_too_few_queries_is_an_error_not_an_empty_model(repo, flat_root, tmp_path):
    """Scene 12 alone has 3 queries: no validation split, so training stops with one ERROR line."""
    model = "results/fine/models/mlp_gt_gtbb/checkpoint.pt"
    args = ["--cores", "2", model, "--config", "benchmark_scenes=[12]", f"flatlandia_root={flat_root}"]
    res = smk(repo, tmp_path, *args)
    assert res.returncode != 0
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    assert errors and "too few queries to train on" in errors[0], res.stderr[-2000:]
    assert not (tmp_path / model).exists()


def test_a_broken_input_after_a_good_run_leaves_nothing_looking_current(repo, flat_root, tmp_path):
    """Build scene 12's queries, then break its reference map: the failed check removes the stale
    outputs it guards, so the next run rebuilds everything after it instead of trusting them."""
    data = tmp_path / "data"
    shutil.copytree(flat_root, data, ignore=shutil.ignore_patterns("*.ply", "*.bin", "*.zip", "MANIFEST.tsv"))
    for p in data.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    wd = tmp_path / "wd"
    wd.mkdir()
    target = "results/12/queries/queries.parquet"
    args = ["--config", f"flatlandia_root={data}", "benchmark_scenes=[12]"]
    assert smk(repo, wd, "--cores", "1", target, *args).returncode == 0
    bad = data / "individual_reference_maps/map_12.json"
    objs = json.loads(bad.read_text())
    objs[3][0][0] = None
    bad.write_text(json.dumps(objs))
    res = smk(repo, wd, "--cores", "1", target, *args)
    assert res.returncode != 0
    assert [line for line in res.stderr.splitlines() if line.startswith("ERROR:")], res.stderr[-2000:]
    assert not (wd / "results/12/ingest/ingest.json").exists()  # the failed check's own output is gone
    plan = smk(repo, wd, "-n", target, *args).stdout
    assert "rule ingest:" in plan and "rule queries:" in plan  # nothing downstream is taken as current
