"""Score your own poses (flatlandia.score, `flatlandia score`, rule external_eval): every bad file is one
`ERROR: <file>: <problem>` line; convention mix-ups are warnings; the solver's own poses, scored as an
external method, give the solver's rows; external runs sit in the fine table, the figures, the query
figures and the viewer. Fast tests on the tiny scene (tests/data/tiny); the workflow runs on two
published scenes (slow)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shutil

import numpy as np
import pandas as pd
import pytest
import tiny_results as tiny_results_folder
import yaml
from conftest import REPO, TINY_SCENE, smk_dry_run
from snakemake_runner import smk

from flatlandia import cli, config, geo, score
from flatlandia.benchmark import fine_rows, metrics
from flatlandia.fine import fine_table
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError
from flatlandia.report import figures, tables
from flatlandia.viewer import page, query_figures, scene_view

#: an errors row's columns that are the solver's own fit, not its pose (an external method has none)
#: the solver's fit of a pose, which poses given from outside do not carry: its inliers and its
#: answer (probability, answered at the threshold)
FIT_COLUMNS = {"confidence", "n_inliers", "n_correct_inliers", "matched_obj_idx", "probability", "answered"}
#: radians(degrees(t)) is t to the last bit or two: headings round-trip to 1e-13 deg
ATOL = 1e-9


@pytest.fixture(scope="module")
def tiny_results(tmp_path_factory):
    """A results folder of the tiny scene as the workflow lays it out (tests/tiny_results.py)."""
    return tiny_results_folder.build(tmp_path_factory.mktemp("tiny_results") / "results")


@pytest.fixture(scope="module")
def tiny_scenes(tiny_results):
    return score.results_scenes(tiny_results)


def _truth(scenes, split="train") -> pd.DataFrame:
    q = pd.concat([b.queries for b in scenes.values()], ignore_index=True)
    return q[q["split"] == split].reset_index(drop=True)


def _metric(t: pd.DataFrame) -> pd.DataFrame:
    return t[["scene", "token", "x_m", "y_m", "theta_deg"]].copy()


def _geographic(t: pd.DataFrame, scenes) -> pd.DataFrame:
    """The same poses as lon, lat and a compass heading (heading = 90 - theta)."""
    frame = scenes[str(t["scene"].iloc[0])].frame
    lonlat = frame.to_lonlat(t[["x_m", "y_m"]].to_numpy(float))
    return pd.DataFrame(
        {
            "scene": t["scene"],
            "token": t["token"],
            "lon": lonlat[:, 0],
            "lat": lonlat[:, 1],
            "heading_deg": 90.0 - t["theta_deg"],
        }
    )


def _noisy(t: pd.DataFrame, seed=0, metres=2.0, degrees=3.0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    out = _metric(t)
    out["x_m"] += rng.normal(0, metres, len(t))
    out["y_m"] += rng.normal(0, metres, len(t))
    out["theta_deg"] += rng.normal(0, degrees, len(t))
    return out


def _write(df: pd.DataFrame, path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    if str(path).endswith(".parquet"):
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False)
    return str(path)


def _cli(capsys, *args) -> tuple[int, list[str]]:
    rc = cli.main(["score", *map(str, args)])
    out = capsys.readouterr()
    return rc, [ln for ln in (out.out + out.err).splitlines() if ln.strip()]


# ---------------------------------------------------------------- bad files: one line each


def _bad_cases(t: pd.DataFrame) -> dict:
    """name -> (file text or frame, suffix, what the message must say)."""
    good = _metric(t)
    tok = str(t["token"].iloc[0])
    hole = good.copy()
    hole.loc[2, "theta_deg"] = np.nan  # an empty cell in the CSV
    nan_text = good.astype(str)
    nan_text.loc[2, "theta_deg"] = "NaN"
    nan_row = good.copy()
    nan_row.loc[4, "y_m"] = np.nan
    inf_row = good.copy()
    inf_row.loc[1, "x_m"] = np.inf
    text_row = good.astype(str)
    text_row.loc[0, "y_m"] = "north"
    return {
        "missing token": (good.drop(columns=["token"]), ".csv", "missing column(s) token"),
        "both forms": (good.assign(lon=1.0, lat=2.0, heading_deg=3.0), ".csv", "both pose forms"),
        "neither form": (good[["scene", "token"]], ".csv", "no pose columns"),
        "half a form": (good.drop(columns=["theta_deg"]), ".csv", "missing column(s) theta_deg"),
        "unknown scene": (good.assign(scene="99"), ".csv", "unknown scene(s) '99'"),
        "unknown token": (pd.concat([good, good.head(1).assign(token="nosuchtoken")]), ".csv", "'nosuchtoken'"),
        "duplicate": (
            pd.concat([good, good.head(1)]),
            ".csv",
            f"duplicate poses of 1 query(ies) in one setting: scene {TINY_SCENE}, token {tok}",
        ),
        "part of a pose": (hole, ".csv", "part of a pose is empty (theta_deg in line 4 (scene"),
        "nan": (nan_text, ".csv", "theta_deg is not a finite number (NaN, inf) in line 4 (scene"),
        "nan parquet": (nan_row, ".parquet", "part of a pose is empty (y_m in row 5 (scene"),  # pandas: NaN -> null
        "inf": (inf_row, ".parquet", "x_m is not a finite number (NaN, inf) in row 2 (scene"),
        "all empty": (good.assign(x_m="", y_m="", theta_deg=""), ".csv", "holds no pose: every row"),
        "not a number": (text_row, ".csv", "y_m is not a number in line 2"),
        "unknown map_type": (good.assign(map_type="rgb"), ".csv", "unknown map_type 'rgb'"),
        "unknown proposal": (good.assign(proposal="coarse-oracle"), ".csv", "unknown proposal 'coarse-oracle'"),
        "negative seconds": (good.assign(seconds=-1.0), ".csv", "seconds is not a number >= 0"),
        "unknown status": (good.assign(status="sure"), ".csv", "status 'sure' in line 2 (scene"),
        "status left empty": (good.assign(status=""), ".csv", "is none of ok, ambiguous, no pose"),
        "no pose beside a pose": (good.assign(status="no pose"), ".csv", "status 'no pose' beside a pose in line 2"),
        "probability above 1": (good.assign(probability=1.5), ".csv", "probability is not a number from 0 to 1"),
        "probability not a number": (good.assign(probability="high"), ".csv", "probability is not a number from 0"),
        "empty file": ("", ".csv", "empty file"),
        "header only": ("scene,token,x_m,y_m,theta_deg\n", ".csv", "holds no poses"),
        "not parquet": ("scene,token\n", ".parquet", "cannot be read as Parquet"),
        "unknown format": ("{}", ".json", "unknown format '.json'"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "missing token",
        "both forms",
        "neither form",
        "half a form",
        "unknown scene",
        "unknown token",
        "duplicate",
        "part of a pose",
        "nan",
        "nan parquet",
        "inf",
        "all empty",
        "not a number",
        "unknown map_type",
        "unknown proposal",
        "negative seconds",
        "unknown status",
        "status left empty",
        "no pose beside a pose",
        "probability above 1",
        "probability not a number",
        "lat out of range",
        "empty file",
        "header only",
        "not parquet",
        "unknown format",
        "no such file",
    ],
)
def test_a_bad_poses_file_is_one_error_line_and_nothing_written(case, tiny_results, tiny_scenes, tmp_path, capsys):
    t = _truth(tiny_scenes)
    if case == "no such file":
        path, want = tmp_path / "nowhere.csv", "no such file"
    elif case == "lat out of range":
        geo_poses = _geographic(t, tiny_scenes)
        geo_poses.loc[3, "lat"] = 123.0
        path, want = tmp_path / "poses.csv", "lat out of range (|lat| > 90 degrees) in line 5"
        _write(geo_poses, path)
    else:
        content, suffix, want = _bad_cases(t)[case]
        path = tmp_path / f"poses{suffix}"
        if isinstance(content, str):
            path.write_text(content)
        else:
            _write(content, path)
    out = tmp_path / "out"
    rc, lines = _cli(capsys, path, "--name", "mine", "--out", out, "--results", tiny_results, "--split", "train")
    assert rc == 1
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ERROR: {path}: "), lines[0]
    assert want in lines[0], lines[0]
    assert "Traceback" not in lines[0]
    assert not out.exists()


def test_unknown_tokens_and_scenes_are_listed(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    many = pd.concat([_metric(t), _metric(t).head(8).assign(token=[f"bad{k}" for k in range(8)])])
    with pytest.raises(InputError) as e:
        score.read_poses(_write(many, tmp_path / "p.csv"), tiny_scenes, "train")
    assert "8 unknown token(s)" in e.value.problem and "'bad0'" in e.value.problem and "and 3 more" in e.value.problem
    assert f"scene {TINY_SCENE}'s train queries are e.g." in e.value.problem
    with pytest.raises(InputError) as e:
        score.read_poses(_write(_metric(t).assign(scene="7"), tmp_path / "q.csv"), tiny_scenes, "train")
    assert e.value.path == str(tmp_path / "q.csv") and f"the benchmark's scenes: {TINY_SCENE}" in e.value.problem


@pytest.mark.parametrize("name", ["solver", "mlp_att", "Mine", "my-method", "1st", ""])
def test_a_name_that_is_not_a_plain_id_or_is_a_builtin_is_refused(name, tiny_results, tiny_scenes, tmp_path, capsys):
    path = _write(_metric(_truth(tiny_scenes)), tmp_path / "p.csv")
    rc, lines = _cli(capsys, path, "--name", name, "--out", tmp_path / "out", "--results", tiny_results)
    assert rc == 1 and len(lines) == 1 and lines[0].startswith("ERROR: --name: ")
    assert not (tmp_path / "out").exists()


def test_a_results_folder_without_the_benchmark_is_one_error_line(tiny_scenes, tmp_path, capsys):
    path = _write(_metric(_truth(tiny_scenes)), tmp_path / "p.csv")
    rc, lines = _cli(capsys, path, "--name", "mine", "--out", tmp_path / "out", "--results", tmp_path / "empty")
    assert rc == 1 and len(lines) == 1 and "dataset_stats_per_scene.parquet: missing" in lines[0]


# ---------------------------------------------------------------- scoring


def test_both_pose_forms_give_the_same_errors(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    noisy = _noisy(t)
    metric = score.read_poses(_write(noisy, tmp_path / "m.csv"), tiny_scenes, "train")
    geographic = score.read_poses(_write(_geographic(noisy, tiny_scenes), tmp_path / "g.parquet"), tiny_scenes, "train")
    assert (metric.form, geographic.form) == ("metric", "geographic")
    a = score.score_run(metric, tiny_scenes, "mine", "depth", "whole").errors
    b = score.score_run(geographic, tiny_scenes, "mine", "depth", "whole").errors
    assert np.allclose(a["error_m"], b["error_m"], atol=1e-6)
    assert np.allclose(a["error_deg"], b["error_deg"], atol=1e-9)
    e_m, e_deg = geo.pose_errors(
        noisy["x_m"], noisy["y_m"], np.radians(noisy["theta_deg"]), t["x_m"], t["y_m"], np.radians(t["theta_deg"])
    )
    assert np.allclose(a["error_m"], e_m) and np.allclose(a["error_deg"], e_deg)


def test_missing_queries_are_failures_as_the_solvers(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    poses = score.read_poses(_write(_noisy(t).iloc[3:], tmp_path / "p.csv"), tiny_scenes, "train")
    run = score.score_run(poses, tiny_scenes, "mine", "depth", "whole")
    e = run.errors
    assert len(e) == len(t) and list(e["token"]) == list(t["token"])
    missing = e["token"].isin(t["token"].iloc[:3])
    assert np.isinf(e.loc[missing, "error_m"]).all() and (e.loc[missing, "error_deg"] == 180.0).all()
    assert e.loc[missing, ["x", "y", "theta_deg"]].isna().all().all()
    assert np.isfinite(e.loc[~missing, "error_m"]).all()
    assert (run.summary["scored"], run.summary["missing"]) == (len(t) - 3, 3)
    assert run.summary["no_pose_pct"] == pytest.approx(100 * 3 / len(t))
    assert "3 missing (failures)" in run.describe()


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_rows_left_empty_are_queries_without_a_pose(suffix, tiny_scenes, tmp_path):
    """A template row whose pose cells are all empty (CSV) or null (Parquet) is a failure, as a row left out."""
    t = _truth(tiny_scenes)
    filled = _noisy(t)
    filled[["x_m", "y_m", "theta_deg"]] = filled[["x_m", "y_m", "theta_deg"]].astype(object)
    filled.iloc[:2, 2:] = None
    poses = score.read_poses(_write(filled, tmp_path / f"template{suffix}"), tiny_scenes, "train")
    assert len(poses.table) == len(t) - 2 and poses.settings() == [("depth", "whole")]
    assert any("2 of its rows have no pose (left empty)" in n for n in poses.notes)
    run = score.score_run(poses, tiny_scenes, "mine", "depth", "whole")
    assert (run.summary["scored"], run.summary["missing"]) == (len(t) - 2, 2)
    assert np.isinf(run.errors["error_m"].iloc[:2]).all()


def test_settings_come_from_the_columns_or_the_defaults(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    plain = score.read_poses(_write(_noisy(t), tmp_path / "plain.csv"), tiny_scenes, "train")
    assert plain.settings() == [("depth", "whole")]
    both = pd.concat([_noisy(t).assign(map_type="gt", proposal="gtbb"), _noisy(t, 1).assign(map_type="depth")])
    two = score.read_poses(_write(both, tmp_path / "two.csv"), tiny_scenes, "train")
    assert two.settings() == [("gt", "gtbb"), ("depth", "whole")]
    with pytest.raises(InputError, match="no poses for map_type gt, proposal whole"):
        score.external_run(tmp_path / "plain.csv", tiny_scenes, "mine", "gt", "whole", split="train")


def test_poses_outside_the_split_are_noted_not_scored(tiny_scenes, tmp_path):
    q = pd.concat([b.queries for b in tiny_scenes.values()], ignore_index=True)
    poses = score.read_poses(_write(_metric(q), tmp_path / "p.csv"), tiny_scenes, "test")
    assert len(poses.table) == int((q["split"] == "test").sum())
    assert poses.outside_split == int((q["split"] != "test").sum())
    assert any("outside the test split" in n for n in poses.notes)


def _round_trip_columns(a: pd.DataFrame, b: pd.DataFrame, skip: set) -> list[str]:
    """Columns of two frames that differ (floats to ATOL, NaN equal to NaN), ``skip`` and timing aside."""
    skip = skip | set(tables.timing_columns(a.columns))
    assert list(a.columns) == list(b.columns)
    return [c for c in a.columns if c not in skip and not tables.columns_equal(a[c], b[c], ATOL)]


def test_round_trip_the_solvers_own_poses_score_as_the_solver(tiny_results, tiny_scenes, tmp_path):
    """The solver's poses written as a poses file and scored as an external method give the solver's
    rows: errors rows in every column but its fit and the timings, table rows in every non-timing
    column but the run's name."""
    builtin = pd.read_parquet(tiny_results / "tables" / "fine_localization.parquet")
    for proposal in ("whole", "gtbb"):
        solver = pd.read_parquet(tiny_results / "fine" / f"solver_depth_{proposal}" / "errors.parquet")
        posed = solver[np.isfinite(solver["x"])]
        poses = posed[["scene", "token", "x", "y", "theta_deg"]].rename(columns={"x": "x_m", "y": "y_m"})
        poses = poses.assign(proposal=proposal)
        run, _ = score.external_run(
            _write(poses, tmp_path / f"{proposal}.csv"), tiny_scenes, "mine", "depth", proposal, split="train"
        )
        assert not _round_trip_columns(run.errors, solver, FIT_COLUMNS | {"method"})
        mine = fine_rows.table_rows([run.summary])
        theirs = builtin[builtin["run"] == f"solver_depth_{proposal}"].reset_index(drop=True)
        answers = set(metrics.ANSWER_COLUMNS)  # the solver's answers: poses from outside carry none
        assert not _round_trip_columns(mine, theirs, {"run", "method", "method_label"} | answers)
        assert mine["trained_on"].iloc[0] == "" and mine["method_label"].iloc[0] == "mine"


# ---------------------------------------------------------------- answers: status and probability


def _answered_file(t: pd.DataFrame) -> tuple[pd.DataFrame, float, float]:
    """A poses file with answers, on the tiny scene's 10 train queries, and its answered share and
    within (5 m, 5 deg) of the answered counted by hand: queries 0-3 ok at the truth (within), 4 ok
    20 m off (answered, not within), 5-6 ambiguous at the truth, 7 ambiguous 20 m off, 8 a row
    without a pose (status no pose), 9 left out. Answered: 5 of 10; within of them: 4 of 5."""
    poses = _metric(t)
    poses.loc[[4, 7], "x_m"] += 20.0
    poses["status"] = ["ok"] * 5 + ["ambiguous"] * 3 + ["no pose", "ok"]
    poses["probability"] = [0.9, 0.95, 0.8, 0.99, 0.75, 0.4, 0.5, 0.3, 0.0, 0.9]
    poses.loc[8, ["x_m", "y_m", "theta_deg"]] = np.nan  # an empty pose: CSV cells left empty
    return poses.iloc[:9], 100 * 5 / 10, 100 * 4 / 5


def test_score_counts_the_answered_from_the_status_column(tiny_results, tiny_scenes, tmp_path, capsys):
    """A poses file with status and probability (as `localize --batch` writes it): `flatlandia score`
    says the answered share and how many of the answered are within (5 m, 5 deg), equal to the count
    by hand; summary.json and scores.md carry them as the fine table's columns; a query without a
    pose (left empty or left out) is not answered, and has probability 0 (the solver's rows say so)."""
    poses, answered, within = _answered_file(_truth(tiny_scenes))
    path = _write(poses, tmp_path / "answers.csv")
    out = tmp_path / "out"
    rc, lines = _cli(capsys, path, "--name", "mine", "--out", out, "--results", tiny_results, "--split", "train")
    assert rc == 0, lines
    said = next(ln for ln in lines if ln.startswith("mine_depth_whole"))
    assert said.endswith(f"; {answered:.1f} % answered (status ok), {within:.1f} % of them within (5 m, 5 deg)"), said
    summary = json.loads((out / "mine_depth_whole" / "summary.json").read_text())
    assert summary["answered_pct"] == pytest.approx(answered) and summary["within_answered_pct"] == pytest.approx(
        within
    )
    assert summary["has_status"] is True
    errors = pd.read_parquet(out / "mine_depth_whole" / "errors.parquet")
    assert errors["answered"].tolist() == [True] * 5 + [False] * 5
    assert errors["probability"].tolist() == pytest.approx([0.9, 0.95, 0.8, 0.99, 0.75, 0.4, 0.5, 0.3, 0.0, 0.0])
    md = (out / "scores.md").read_text()
    head = next(ln for ln in md.splitlines() if ln.startswith("| method |"))
    assert head.endswith("| answered % | 5 m & 5° of the answered |"), head
    row = next(ln for ln in md.splitlines() if ln.startswith("| mine (yours) |"))
    assert row.endswith(f"| {answered:.1f} | {within:.1f} |"), row


def test_a_file_without_status_scores_as_before(tiny_results, tiny_scenes, tmp_path, capsys):
    """An outside method's file (no status, no probability) scores as it always did: every pose it
    gives answered, no probability, nothing new said on the terminal or in scores.md."""
    poses = _metric(_truth(tiny_scenes)).iloc[:9]
    path = _write(poses, tmp_path / "plain.csv")
    out = tmp_path / "out"
    rc, lines = _cli(capsys, path, "--name", "mine", "--out", out, "--results", tiny_results, "--split", "train")
    assert rc == 0, lines
    assert not any("answered" in ln for ln in lines), lines
    summary = json.loads((out / "mine_depth_whole" / "summary.json").read_text())
    assert summary["has_status"] is False and summary["answered_pct"] == 100.0
    errors = pd.read_parquet(out / "mine_depth_whole" / "errors.parquet")
    assert errors["answered"].all() and errors["probability"].isna().all()
    assert "answered" not in (out / "scores.md").read_text()


# ---------------------------------------------------------------- plausibility warnings


def _warnings(df, tmp_path, scenes, name="p.csv"):
    poses = score.read_poses(_write(df, tmp_path / name), scenes, "train")
    return score.plausibility(poses, scenes)


def test_honest_poses_raise_no_warning_poor_ones_neither(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    assert _warnings(_noisy(t), tmp_path, tiny_scenes) == []
    assert _warnings(_geographic(_noisy(t), tiny_scenes), tmp_path, tiny_scenes, "g.csv") == []
    rng = np.random.default_rng(3)
    poor = _metric(t).assign(
        x_m=rng.uniform(-200, 200, len(t)), y_m=rng.uniform(-200, 200, len(t)), theta_deg=rng.uniform(-180, 180, len(t))
    )
    assert _warnings(poor, tmp_path, tiny_scenes, "poor.csv") == []


def test_swapped_lon_lat_stops_the_file_and_a_few_swapped_rows_are_a_warning(
    tiny_scenes, tmp_path, capsys, tiny_results
):
    t = _truth(tiny_scenes)
    g = _geographic(_noisy(t), tiny_scenes)
    swapped = g.rename(columns={"lon": "lat", "lat": "lon"})
    with pytest.raises(
        InputError, match=r"10 of its 10 poses look wrong .*lon and lat look swapped.*nothing was scored"
    ):
        _warnings(swapped, tmp_path, tiny_scenes)
    # x_m and y_m swapped in every row: each pose still lies in the tiny street's scene (80 m long), so no
    # row is suspected; the file's median error says it (the file is scored)
    xy = _noisy(t, metres=0.5).rename(columns={"x_m": "y_m", "y_m": "x_m"})
    w = _warnings(xy, tmp_path, tiny_scenes, "xy.csv")
    assert len(w) == 1 and w[0].startswith("xy.csv: x_m and y_m look swapped: swapped, the median position"), w
    some = pd.concat([swapped.iloc[:3], g.iloc[3:]], ignore_index=True)[["scene", "token", "lon", "lat", "heading_deg"]]
    w = _warnings(some, tmp_path, tiny_scenes, "some.csv")
    assert len(w) == 1 and "3 of its 10 poses look wrong" in w[0] and "lon and lat look swapped" in w[0], w
    assert all(f"line {k}" in w[0] for k in (2, 3, 4)) and "line 5" not in w[0], w
    rc, lines = _cli(
        capsys,
        tmp_path / "some.csv",
        "--name",
        "mine",
        "--out",
        tmp_path / "o",
        "--results",
        tiny_results,
        "--split",
        "train",
    )
    assert rc == 0 and any(ln.startswith("WARNING: some.csv: 3 of its 10 poses look wrong") for ln in lines), lines
    assert (tmp_path / "o" / "mine_depth_whole" / "errors.parquet").exists()  # a warning writes the scores
    args = ("--name", "mine", "--out", tmp_path / "o2", "--results", tiny_results, "--split", "train")
    rc, lines = _cli(capsys, tmp_path / "p.csv", *args)
    assert rc == 1 and len(lines) == 1 and not (tmp_path / "o2").exists(), lines
    assert lines[0].startswith(f"ERROR: {tmp_path / 'p.csv'}: 10 of its 10 poses look wrong"), lines


def test_a_wrong_pose_inside_its_scene_is_no_swap(tiny_scenes, tmp_path):
    """The solver's own poses drew "x_m and y_m look swapped" for one wrong pose that lay inside its
    scene (scene 10; issue 45): read swapped it fell near its truth. A pose inside its scene is a
    method's error, whatever a swap would make of it; as lon/lat neither."""
    t = _truth(tiny_scenes)
    poses = _noisy(t, metres=0.3)
    k = int(np.argmax(np.abs(t["x_m"] - t["y_m"])))  # the camera farthest from the line x = y
    assert abs(t["x_m"][k] - t["y_m"][k]) > 20  # put at its swapped truth, it is 28 m and more off
    poses.loc[k, ["x_m", "y_m"]] = t.loc[k, ["y_m", "x_m"]].to_numpy(float)
    box = score.scene_extents(tiny_scenes)[TINY_SCENE]
    assert box[0] < poses["x_m"][k] < box[2] and box[1] < poses["y_m"][k] < box[3]  # inside the scene
    assert _warnings(poses, tmp_path, tiny_scenes) == []
    assert _warnings(_geographic(poses, tiny_scenes), tmp_path, tiny_scenes, "g.csv") == []


def test_a_pose_outside_its_scene_that_a_swap_puts_in_it_is_a_swap(tiny_scenes, tmp_path):
    """The other side: given, the pose lies where no method could have put it (outside the scene), and
    swapped it lies in the scene near its truth. The tiny scene moved 3 km east of its origin, so that
    x_m and y_m swapped leave it."""
    moved = {
        s: dataclasses.replace(
            b, ref=b.ref.assign(x_m=b.ref["x_m"] + 3000.0), queries=b.queries.assign(x_m=b.queries["x_m"] + 3000.0)
        )
        for s, b in tiny_scenes.items()
    }
    t = _truth(moved)
    poses = _noisy(t, metres=0.3)
    poses.loc[:2, ["x_m", "y_m"]] = poses.loc[:2, ["y_m", "x_m"]].to_numpy(float)
    w = _warnings(poses, tmp_path, moved)
    assert len(w) == 1 and "3 of its 10 poses look wrong" in w[0] and "x_m and y_m look swapped" in w[0], w
    assert all(f"line {k}" in w[0] for k in (2, 3, 4)) and "line 5" not in w[0], w


def test_radians_for_degrees_and_back_are_warnings(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    noisy = _noisy(t, degrees=1.0)
    w = _warnings(noisy.assign(theta_deg=np.radians(noisy["theta_deg"])), tmp_path, tiny_scenes, "rad.csv")
    assert len(w) == 1 and "theta_deg values look like radians" in w[0], w
    w = _warnings(noisy.assign(theta_deg=np.degrees(noisy["theta_deg"])), tmp_path, tiny_scenes, "twice.csv")
    assert len(w) == 1 and "converted to degrees twice" in w[0], w
    g = _geographic(noisy, tiny_scenes)
    w = _warnings(g.assign(heading_deg=np.radians(g["heading_deg"])), tmp_path, tiny_scenes, "grad.csv")
    assert len(w) == 1 and "heading_deg values look like radians" in w[0], w
    w = _warnings(g.assign(heading_deg=noisy["theta_deg"]), tmp_path, tiny_scenes, "theta.csv")
    assert len(w) == 1 and "counter-clockwise from east" in w[0], w


# ---------------------------------------------------------------- the command


def test_cli_writes_the_runs_and_scores_md(tiny_results, tiny_scenes, tmp_path, capsys):
    t = _truth(tiny_scenes)
    both = pd.concat([_noisy(t).iloc[2:].assign(proposal="whole"), _noisy(t, 1).assign(proposal="gtbb", seconds=0.01)])
    path = _write(both, tmp_path / "poses.csv")
    out = tmp_path / "scores"
    rc, lines = _cli(capsys, path, "--name", "mine", "--out", out, "--results", tiny_results, "--split", "train")
    assert rc == 0, lines
    text = "\n".join(lines)
    assert (
        f"mine_depth_whole (depth local maps, whole map proposals): {len(t)} train queries, {len(t) - 2} scored, 2 missing"
        in text
    )
    assert "recall 1 / 3 / 5 m" in text and "median" in text
    for run in ("mine_depth_whole", "mine_depth_gtbb"):
        e = pd.read_parquet(out / run / "errors.parquet")
        assert list(e.columns) == list(
            pd.read_parquet(tiny_results / "fine" / "solver_depth_whole" / "errors.parquet").columns
        )
        assert files.read_parquet_metadata(out / run / "errors.parquet")["run"] == run
        s = json.loads((out / run / "summary.json").read_text())
        assert s["run"] == run and s["external"] and set(metrics.RECALL_COLUMNS) <= set(s)
    md = (out / "scores.md").read_text()
    assert "| mine (yours) |" in md and "| geometric solver |" in md
    assert md.count("recall 1 m") == 2 and "recall 5°" in md and "10 m & 20°" in md
    assert json.loads((out / "mine_depth_gtbb" / "summary.json").read_text())["mean_query_s"] == pytest.approx(0.01)


# ---------------------------------------------------------------- config, table, figures, viewer


def test_config_entries_get_their_defaults_and_names_are_checked():
    full = config.resolve({"external": [{"name": "mine", "poses": "p.csv"}]})
    assert score.external_entries(full["external"]) == [
        {"name": "mine", "poses": "p.csv", "map_types": ["depth"], "proposals": ["whole"]}
    ]
    for bad in (
        {"name": "solver", "poses": "p"},
        {"name": "Mine", "poses": "p"},
        {"name": "m"},
        {"name": "m", "poses": "p", "x": 1},
    ):
        with pytest.raises(config.ConfigError, match="external.0"):
            config.resolve({"external": [bad]})
    with pytest.raises(config.ConfigError, match="'external.1.name': 'mine' is the name of an earlier entry"):
        score.external_entries([{"name": "mine", "poses": "a"}, {"name": "mine", "poses": "b"}])


def test_builtin_names_are_the_vocabularys_in_the_figures_and_the_fine_table():
    """Every built-in method has its colour in the figures and its label in the fine table, in the
    vocabulary's order (the schema's enums: tests/test_vocabulary.py)."""
    from flatlandia import vocabulary

    assert tuple(figures.METHOD_COLOURS) == vocabulary.METHODS == tuple(fine_rows.METHOD_LABELS)
    with pytest.raises(InputError, match="built-in method"):
        score.check_name("mlp_att")


def test_the_fine_table_takes_an_external_row(tiny_results, tiny_scenes, tmp_path):
    poses = score.read_poses(_write(_noisy(_truth(tiny_scenes)), tmp_path / "p.csv"), tiny_scenes, "train")
    run = score.score_run(poses, tiny_scenes, "mine", "depth", "whole")
    builtin = pd.read_parquet(tiny_results / "tables" / "fine_localization.parquet")
    df = pd.concat([builtin, fine_rows.table_rows([run.summary])], ignore_index=True)
    tables.write_table(df, "fine_localization", tmp_path / "t.parquet", tmp_path / "t.md", tmp_path / "t.tex")
    row = df[df["method"] == "mine"].iloc[0]
    assert (row["method_label"], row["trained_on"], row["epochs"], row["strategy"]) == ("mine", "", 0, "whole map")
    md = fine_table.render_markdown(df)
    assert "| mine | whole map |" in md and "| mine | whole map | depth |" in md  # Table 5 and the recalls


def _errors_of_runs(tiny_results, tiny_scenes, tmp_path):
    poses = score.read_poses(_write(_noisy(_truth(tiny_scenes)), tmp_path / "p.csv"), tiny_scenes, "train")
    errors = {"mine_depth_whole": score.score_run(poses, tiny_scenes, "mine", "depth", "whole").errors}
    for run in ("solver_depth_whole", "solver_depth_gtbb"):
        errors[run] = pd.read_parquet(tiny_results / "fine" / run / "errors.parquet")
    return errors


def test_figures_style_external_methods_after_the_builtins(tiny_results, tiny_scenes, tmp_path):
    assert list(figures.METHOD_COLOURS) == ["solver", "solver-noprior", "mlp", "mlp_att", "gat", "gat_att"]
    taken = set(figures.METHOD_COLOURS.values()) | {figures.TRUTH_COLOUR, query_figures.WRONG_COLOUR}
    assert not set(figures.EXTERNAL_COLOURS) & taken and not set(figures.EXTERNAL_COLOURS) & set(
        page.SPLIT_COLOURS.values()
    )
    assert figures.method_colour("mine") == figures.method_colour("mine") in figures.EXTERNAL_COLOURS
    runs = sorted(
        map(figures.Run.parse, ["mine_gt_gtbb", "gat_gt_gtbb", "solver_depth_gtbb", "abc_gt_gtbb"]),
        key=figures.Run.sort_key,
    )
    assert [r.name for r in runs] == ["solver_depth_gtbb", "gat_gt_gtbb", "abc_gt_gtbb", "mine_gt_gtbb"]
    assert figures.Run.parse("mine_depth_whole").label == "mine, depth local map, whole reference map"
    errors = _errors_of_runs(tiny_results, tiny_scenes, tmp_path)
    fig = figures.error_cdf_figure(errors)
    legend = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert legend[:2] == ["solver", "mine"], legend
    curves = {ln.get_label(): ln for ax in fig.axes for ln in ax.get_lines() if ln.get_label() in errors}
    from matplotlib.colors import to_hex

    assert to_hex(curves["mine_depth_whole"].get_color()) == figures.method_colour("mine")
    figures.pyplot().close(fig)
    figures.pyplot().close(figures.error_vs_objects_figure(errors, min_queries=1))


def test_viewer_and_query_figures_show_an_external_run_without_matches(tiny_results, tiny_scenes, tmp_path):
    errors = _errors_of_runs(tiny_results, tiny_scenes, tmp_path)
    b = tiny_scenes[TINY_SCENE]
    view = scene_view.scene_view(TINY_SCENE, b.ref, b.queries, errors)
    assert view.featured == ("solver_depth_gtbb", "mine_depth_whole")
    q = next(q for q in view.queries if q.estimate("mine_depth_whole"))
    est = q.estimate("mine_depth_whole")
    assert est.matches is None and est.has_pose and est.run.external
    data = page.page_data(view)
    mine = next(r for r in data["runs"] if r["name"] == "mine_depth_whole")
    assert (
        mine["featured"]
        and mine["colour"] == figures.method_colour("mine")
        and mine["label"] == "mine, depth local map"
    )
    assert "mine_depth_whole" in page.render(view)
    fig = query_figures.query_figure(view, q)
    texts = [t.get_text() for ax in fig.axes for leg in [ax.get_legend()] if leg for t in leg.get_texts()]
    assert any(t.startswith("mine, depth local map, whole reference map: ") for t in texts), texts
    figures.pyplot().close(fig)
    only_mine = scene_view.scene_view(TINY_SCENE, b.ref, b.queries, {"mine_depth_whole": errors["mine_depth_whole"]})
    assert only_mine.featured == ("mine_depth_whole",)
    figures.pyplot().close(query_figures.worst_figure(only_mine))


def test_dry_run_plans_the_external_runs_beside_the_builtins(repo, tmp_path):
    poses = tmp_path / "mine.csv"
    poses.write_text("scene,token,x_m,y_m,theta_deg\n")
    cfg = tmp_path / "ext.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "external": [{"name": "mine", "poses": str(poses), "map_types": ["gt", "depth"]}],
                "fine": {"runs": {"methods": ["solver"], "map_types": ["depth"], "proposals": ["whole"], "extra": []}},
            }
        )
    )
    tiny = str(REPO / "config" / "test" / "tiny.yaml")
    res = smk_dry_run(
        repo,
        tmp_path,
        "results/tables/fine_localization.parquet",
        "results/figures/fine_error_cdf.png",
        "--configfile",
        tiny,
        str(cfg),
    )
    assert res.returncode == 0, res.stderr[-3000:] + res.stdout[-3000:]
    jobs = res.stdout
    assert "external_eval" in jobs and "results/external/mine_gt_whole/errors.parquet" in jobs
    assert "results/external/mine_depth_whole/summary.json" in jobs and "fine_train" not in jobs
    assert "results/fine/mine_" not in jobs  # the built-in runs' tree holds no external run
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"external": [{"name": "mine", "poses": "a"}, {"name": "mine", "poses": "b"}]}))
    res = smk_dry_run(repo, tmp_path, "--configfile", tiny, str(bad))
    assert res.returncode != 0 and "ERROR: config: 'external.1.name'" in res.stderr + res.stdout


# ---------------------------------------------------------------- the workflow on two published scenes (slow)


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def external_workflow(repo, flat_root, tmp_path_factory):
    """Two scenes, the solver on depth maps and the whole map; then, with the solver's own poses
    as external method `mine` and noisy geographic poses as `noisy` (two settings) in the config,
    the fine table, the error figures, the query figures and a viewer again."""
    wd = tmp_path_factory.mktemp("external_workflow")
    base = [
        "--configfile",
        str(REPO / "config" / "test" / "two_scenes.yaml"),
        str(wd / "fine.yaml"),
        "--config",
        f"flatlandia_root={flat_root}",
    ]
    fine = {"fine": {"runs": {"methods": ["solver"], "map_types": ["depth"], "proposals": ["whole"], "extra": []}}}
    (wd / "fine.yaml").write_text(yaml.safe_dump(fine))
    targets = [
        "results/tables/fine_localization.parquet",
        "results/tables/dataset_stats.parquet",
        "results/figures/fine_error_cdf.png",
        "results/9/queries/worst_queries.png",
        "results/9/maps/viewer.html",
    ]
    first = smk(repo, wd, "--cores", "2", *targets, *base)
    assert first.returncode == 0, first.stderr[-4000:]
    solver_run = wd / "results" / "fine" / "solver_depth_whole"
    before = {p.name: _digest(p) for p in solver_run.iterdir()}
    table_before = pd.read_parquet(wd / "results" / "tables" / "fine_localization.parquet")
    solver = pd.read_parquet(solver_run / "errors.parquet")
    posed = solver[np.isfinite(solver["x"])]
    posed[["scene", "token", "x", "y", "theta_deg"]].rename(columns={"x": "x_m", "y": "y_m"}).to_csv(
        wd / "mine.csv", index=False
    )
    parts = []
    for s in ("9", "12"):
        sc = score.read_scene(
            wd / f"results/{s}/maps/reference_map.parquet", wd / f"results/{s}/queries/queries.parquet"
        )
        frame, q = sc.frame, sc.queries[sc.queries["split"] == "test"]
        lonlat = frame.to_lonlat(q[["x_m", "y_m"]].to_numpy(float) + 2.0)
        parts.append(
            pd.DataFrame(
                {
                    "scene": s,
                    "token": q["token"],
                    "lon": lonlat[:, 0],
                    "lat": lonlat[:, 1],
                    "heading_deg": 90.0 - q["theta_deg"] + 4.0,
                }
            )
        )
    noisy = pd.concat(parts, ignore_index=True)
    pd.concat([noisy.assign(map_type="gt"), noisy.assign(map_type="depth")]).to_parquet(
        wd / "noisy.parquet", index=False
    )
    ext = {
        "external": [
            {"name": "mine", "poses": "mine.csv"},
            {"name": "noisy", "poses": str(wd / "noisy.parquet"), "map_types": ["gt", "depth"]},
        ]
    }
    (wd / "ext.yaml").write_text(yaml.safe_dump(ext))
    second = smk(repo, wd, "--cores", "2", *targets, *base[:3], str(wd / "ext.yaml"), *base[3:])
    assert second.returncode == 0, second.stderr[-4000:]
    args = [*base[:3], str(wd / "ext.yaml"), *base[3:]]
    return {"wd": wd, "before": before, "table_before": table_before, "stderr": second.stderr, "args": args}


@pytest.mark.slow  # the published data (flat_root)
def test_workflow_scores_external_methods_into_the_table_and_figures(external_workflow):
    wd = external_workflow["wd"]
    res = wd / "results"
    assert "external_eval" in external_workflow["stderr"] and "rule fine_eval" not in external_workflow["stderr"]
    # scoring never changes the built-in results
    assert {p.name: _digest(p) for p in (res / "fine" / "solver_depth_whole").iterdir()} == external_workflow["before"]
    table = pd.read_parquet(res / "tables" / "fine_localization.parquet")
    assert list(table["run"]) == ["solver_depth_whole", "mine_depth_whole", "noisy_gt_whole", "noisy_depth_whole"]
    pd.testing.assert_frame_equal(table.iloc[:1], external_workflow["table_before"])
    # the round trip: the solver's own poses give the solver's row in every non-timing column but its
    # answers (a poses file carries no probability)
    assert not _round_trip_columns(
        table.iloc[[1]].reset_index(drop=True),
        table.iloc[[0]].reset_index(drop=True),
        {"run", "method", "method_label"} | set(metrics.ANSWER_COLUMNS),
    )
    noisy = table[table["method"] == "noisy"]
    assert np.allclose(noisy["median_m"], 2 * math.sqrt(2), atol=1e-6)  # 2 m east and north
    assert np.allclose(noisy["median_deg"], 4.0, atol=1e-6)
    assert {c.name for c in tables.SCHEMAS["fine_localization"]} == set(table.columns)
    md = (res / "tables" / "fine_localization.md").read_text()
    assert "| noisy | whole map | gt |" in md and "| mine | whole map | depth |" in md
    html = (res / "9" / "maps" / "viewer.html").read_text()
    assert "noisy_gt_whole" in html and "mine_depth_whole" in html
    assert (res / "figures" / "fine_error_cdf.png").stat().st_size > 0
    assert any((res / "9" / "queries" / "figures").glob("*.png"))
    log = (wd / "logs" / "external_eval" / "mine_depth_whole.log").read_text()
    assert "mine_depth_whole (depth local maps, whole map proposals)" in log


@pytest.mark.slow  # the published data (flat_root)
def test_cli_end_to_end_on_a_workflow_results_folder(external_workflow, tmp_path, capsys):
    wd = external_workflow["wd"]
    res = wd / "results"
    rc, lines = _cli(capsys, wd / "mine.csv", "--name", "theirs", "--out", tmp_path / "out", "--results", res)
    assert rc == 0, lines
    ours = json.loads((tmp_path / "out" / "theirs_depth_whole" / "summary.json").read_text())
    workflow = json.loads((res / "external" / "mine_depth_whole" / "summary.json").read_text())
    same = {k for k in workflow if k not in ("method", "method_slug", "run", "poses")}
    assert {k: ours[k] for k in same} == {k: workflow[k] for k in same}
    md = (tmp_path / "out" / "scores.md").read_text()
    assert "| theirs (yours) |" in md and "| geometric solver |" in md and "| mine |" in md


@pytest.mark.slow  # the published data (flat_root)
def test_an_edited_poses_file_rescores_its_runs(external_workflow, repo):
    wd = external_workflow["wd"]
    poses = wd / "mine.csv"
    shutil.copy(poses, wd / "mine.keep")
    poses.write_text("".join(poses.read_text().splitlines(keepends=True)[:-1]))  # one pose fewer
    res = smk(repo, wd, "-n", "results/tables/fine_localization.parquet", *external_workflow["args"])
    shutil.copy(wd / "mine.keep", poses)
    assert res.returncode == 0, res.stderr[-3000:]
    planned = res.stdout + res.stderr
    # the edited method's run is planned again, the other method's is not (its files are only inputs of the table)
    assert "output: results/external/mine_depth_whole/errors.parquet" in planned
    assert "output: results/external/noisy_gt_whole/errors.parquet" not in planned
