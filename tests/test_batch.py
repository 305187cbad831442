"""Localize a whole split in one command (`flatlandia localize --batch`, flatlandia.localize.batch): a new
user's flow export -> batch localize -> score -> table row on the tiny scene (fast lane): the poses
file scores as the solver's whole-map rows of the fine table; the same poses from the export and
from the results folder, through a city index in each query's own scene frame; fixes per query;
bad input as one ERROR line. On the published run (slow): every test query, the fine table's
solver rows reproduced."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import TINY_SCENE
from one_tile_city import write_one_tile_city
from tiny_results import builtin_summary, tiny_scene

from flatlandia import cli, config, geo, paths, score
from flatlandia.benchmark import fine_rows, metrics, solver_runs
from flatlandia.data import export, reference_map
from flatlandia.localize import batch
from flatlandia.plumbing import files
from flatlandia.report import tables

#: the fine table's columns that are timings (query seconds) or name the run
NAME_COLUMNS = {"run", "method", "method_label"}
TEXT = {"scene": str, "token": str}
#: the tiny scene's test split holds one query: the flow runs on its train split (10 queries)
SPLIT = "train"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A results folder of the tiny scene laid out as the workflow writes it (reference map, queries,
    the benchmark record with the scene's city, the solver's whole-map runs on both map types and
    their fine table: rule fine_eval's functions) and its export, written as rules export_scene and
    export_index write it."""
    root = tmp_path_factory.mktemp("tiny_run")
    results = root / "results"
    tiny = tiny_scene()
    meta, q = tiny.meta, tiny.queries
    tiny.write(results)
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE], "city": ["Flatland"]}), results / score.BENCHMARK_RECORD)
    ref = pd.read_parquet(results / TINY_SCENE / "maps" / "reference_map.parquet")
    summaries = []
    for map_type in ("gt", "depth"):
        for proposal, label in (("whole", "whole map"), ("gtbb", "GT-BB")):
            e = solver_runs.solver_errors(
                [(ref, q)], map_type, proposal, config.section_defaults("solver"), split=SPLIT
            )
            e["strategy"] = label
            folder = results / "fine" / f"solver_{map_type}_{proposal}"
            files.write_parquet(e, folder / "errors.parquet")
            summaries.append(builtin_summary(e, "solver", map_type, proposal, label, ref))
            files.write_json(files.json_safe(summaries[-1]), folder / "summary.json")
    files.write_parquet(fine_rows.table_rows(summaries), results / "tables" / "fine_localization.parquet")
    ex = results / "export"
    out = export.scene_export(TINY_SCENE, ref, meta, q)
    for name in ("reference_map", "queries", "local_maps", "proposals", "ground_truth"):
        files.write_text(export.csv_text(out[name]), ex / TINY_SCENE / f"{name}.csv")
    files.write_text(json.dumps(out["reference_geojson"], indent=1) + "\n", ex / TINY_SCENE / "reference_map.geojson")
    files.write_json(out["frame"], ex / TINY_SCENE / "frame.json")
    idx = export.index_export([{"scene": TINY_SCENE, "city": "Flatland", "ref": ref, "meta": meta, "queries": q}], [])
    for name in ("classes", "scenes", "template"):
        files.write_text(export.csv_text(idx[name]), ex / f"{'poses_template' if name == 'template' else name}.csv")
    return results


def _cli(capsys, *args) -> tuple[int, str, str]:
    status = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return status, out.out, out.err


#: positions come back bit for bit; headings go through degrees in the poses file (the solver's
#: radians, written as degrees, read back as radians): errors equal to 1e-13 deg
ATOL = 1e-9


def _row_differences(mine: pd.DataFrame, theirs: pd.DataFrame) -> list[str]:
    """Columns of two fine-table rows that differ, timings and the run's name aside (floats to
    ATOL); the answers' columns (% answered, within of the answered, answerable, ECE) included: the
    poses file carries each query's status and probability."""
    skip = NAME_COLUMNS | set(tables.timing_columns(mine.columns))
    assert list(mine.columns) == list(theirs.columns)
    return [c for c in mine.columns if c not in skip and not tables.columns_equal(mine[c], theirs[c], ATOL)]


@pytest.mark.parametrize("map_type, proposal", [("gt", "whole"), ("depth", "whole"), ("depth", "gtbb")])
def test_export_batch_score_gives_the_solvers_table_row(tiny_run, tmp_path, capsys, map_type, proposal):
    """A new user's flow on the tiny scene: the export -> `flatlandia localize --batch` -> `flatlandia
    score` -> scores.md and a fine-table row equal to the solver's row of that setting (the whole map,
    or each query's GT-BB box from the export's proposals.csv) in every column but the run's name and
    its timings."""
    poses = tmp_path / "poses.csv"
    status, out, err = _cli(
        capsys,
        *("localize", "--batch", tiny_run / "export", "--split", SPLIT, "--map-type", map_type, "--out", poses),
        *("--proposal", proposal),
    )
    assert status == 0, out + err
    assert f"wrote {poses}" in out and "10 queries, 10 localized" in out
    written = pd.read_csv(poses, dtype=TEXT)
    assert list(written.columns) == batch.POSE_COLUMNS + batch.EXTRA_COLUMNS
    assert (written["proposal"] == proposal).all() and (written["map_type"] == map_type).all()
    status, out, err = _cli(
        capsys,
        *("score", poses, "--name", "batch", "--out", tmp_path / "scores", "--results", tiny_run, "--split", SPLIT),
    )
    assert status == 0, out + err
    run = f"batch_{map_type}_{proposal}"
    summary = json.loads((tmp_path / "scores" / run / "summary.json").read_text())
    mine = fine_rows.table_rows([summary])
    builtin = pd.read_parquet(tiny_run / "tables" / "fine_localization.parquet")
    theirs = builtin[builtin["run"] == f"solver_{map_type}_{proposal}"].reset_index(drop=True)
    assert not _row_differences(mine, theirs)
    errors = pd.read_parquet(tmp_path / "scores" / run / "errors.parquet")
    solver = pd.read_parquet(tiny_run / "fine" / f"solver_{map_type}_{proposal}" / "errors.parquet")
    assert errors["x"].tolist() == solver["x"].tolist() and errors["y"].tolist() == solver["y"].tolist()
    assert np.allclose(errors["error_deg"], solver["error_deg"], atol=1e-9, rtol=0)
    md = (tmp_path / "scores" / "scores.md").read_text()
    assert "| batch (yours) |" in md and "| geometric solver |" in md
    # scores.md carries % within (5 m, 5°) (the README's headline) and the fine table's recall columns
    head = next(line for line in md.splitlines() if line.startswith("| method |"))
    cells = [c.strip() for c in head.strip("|").split("|")]
    assert cells[4:9] == ["0.5 m & 2°", "1 m & 5°", "5 m & 5°", "5 m & 10°", "10 m & 20°"]
    assert cells[9:15] == ["recall 1 m", "recall 3 m", "recall 5 m", "recall 1°", "recall 3°", "recall 5°"]
    for label in ("batch (yours)", "geometric solver"):
        row = next(line for line in md.splitlines() if line.startswith(f"| {label} |"))
        assert row.split("|")[7].strip() == f"{theirs[metrics.WITHIN_COLUMN].iloc[0]:.1f}"
    assert f"{theirs[metrics.WITHIN_COLUMN].iloc[0]:.1f} % within (5 m, 5 deg)" in out
    answered = f"{theirs['answered_pct'].iloc[0]:.1f} % answered (status ok), "
    assert answered in out, out


def test_the_poses_file_carries_each_answer(tiny_run, tmp_path):
    """Each row's status (of the known set) and calibrated probability as `flatlandia localize`
    answers the query, its best alternative (pose and probability; empty when it has none), and
    `seconds` the solver's time of that query alone."""
    from flatlandia import localize, vocabulary

    b = batch.localize_batch(tiny_run, SPLIT, "depth", progress=False)
    path = batch.write_poses(b, tmp_path / "poses.csv")
    p = pd.read_csv(path, dtype=TEXT)
    assert list(p.columns) == batch.POSE_COLUMNS + batch.EXTRA_COLUMNS
    assert set(p["status"]) <= set(vocabulary.STATUSES) and p["status"].notna().all()
    threshold = config.section_defaults("solver")["answer_probability"]
    posed = p[p["found"]]
    assert ((posed["probability"] >= threshold) == (posed["status"] == vocabulary.ANSWERED)).all()
    assert ((p["probability"] >= 0) & (p["probability"] <= 1)).all()
    m = localize.load_map(tiny_run / TINY_SCENE / "maps" / "reference_map.parquet")
    queries = batch.open_source(tiny_run).queries(TINY_SCENE, SPLIT, "depth")
    with_alternative = 0
    for q, row in zip(queries, p.itertuples(index=False), strict=True):
        answer = localize.localize(m, q, "depth", alternatives=1)
        assert (row.status, row.probability) == (answer["status"], pytest.approx(answer["probability"], abs=1e-12))
        alt = answer["alternatives"][:1]
        got = [getattr(row, c) for c in batch.ALTERNATIVE_COLUMNS]
        if alt:
            with_alternative += 1
            want = [alt[0]["x_m"], alt[0]["y_m"], alt[0]["theta_deg"], alt[0]["probability"]]
            assert got == pytest.approx(want, abs=1e-9)
        else:
            assert all(math.isnan(v) for v in got)
    assert with_alternative, "no query of the tiny scene has an alternative: the columns are untested"
    assert f"{int((p['status'] == vocabulary.ANSWERED).sum())} answered" in b.describe()


def test_no_querys_seconds_holds_the_solvers_compilation(tiny_run, monkeypatch):
    """The batch solves its first query once, untimed, before it times any: the kernels the solver
    compiles on their first call (numba; 8.5 s with an empty cache on the default run's depth maps,
    20 s in issue 45) never land in a query's `seconds`. Compilation stood for by a first call
    that sleeps; the first query's seconds stay near the median."""
    import time

    from flatlandia import solver

    locate, calls = solver.locate, []

    def first_call_compiles(*args, **kwargs):
        if not calls:
            time.sleep(1.0)
        calls.append(1)
        return locate(*args, **kwargs)

    monkeypatch.setattr(solver, "locate", first_call_compiles)
    p = batch.localize_batch(tiny_run, SPLIT, "gt", progress=False).poses
    seconds = p["seconds"].to_numpy(float)
    assert len(calls) == len(p) + 1  # the warm-up, then each query once
    assert seconds[0] < np.median(seconds) + 0.25, seconds
    assert seconds.max() < 0.5, seconds


def test_tokens_read_as_floats_get_a_one_line_hint(tiny_run, tmp_path, capsys):
    """A template filled after reading it without dtype=str: tokens '...0' or in scientific notation
    are refused in one line that says they look like floats and how to read them."""
    template = pd.read_csv(tiny_run / "export" / "poses_template.csv", dtype=TEXT)
    q = pd.read_parquet(tiny_run / TINY_SCENE / "queries" / "queries.parquet")
    for spoil in (lambda t: f"{int(t)}.0", lambda t: f"{float(t):.14e}"):
        poses = q[q["split"] == SPLIT][["scene", "token", "x_m", "y_m", "theta_deg"]].copy()
        poses["token"] = [spoil(t) for t in poses["token"]]
        poses.to_csv(tmp_path / "floats.csv", index=False)
        status, _, out = _cli(
            capsys,
            *("score", tmp_path / "floats.csv", "--name", "f", "--out", tmp_path / "s", "--results", tiny_run),
            *("--split", SPLIT),
        )
        assert status == 1 and len(out.strip().splitlines()) == 1 and len(out) < 700, out
        assert "look like numbers read as floats" in out and "dtype=str" in out
    assert len(template)  # the template itself holds the tokens as text


def test_the_export_and_the_results_folder_give_the_same_poses(tiny_run, tmp_path):
    """The export's files (reference_map.geojson, local_maps.csv, proposals.csv, ground_truth.csv's
    train cameras) hold the workflow's values exactly: the batch from either source gives the same
    poses, on the whole map and on the GT-BB boxes."""
    for map_type, proposal in itertools.product(("gt", "depth"), ("whole", "gtbb")):
        a = batch.localize_batch(tiny_run / "export", SPLIT, map_type, progress=False, proposal=proposal).poses
        b = batch.localize_batch(tiny_run, SPLIT, map_type, progress=False, proposal=proposal).poses
        for c in ("scene", "token", "x_m", "y_m", "theta_deg", "found", "located_scene"):
            assert a[c].tolist() == b[c].tolist(), (map_type, proposal, c)
    assert set(a["located_scene"]) == {TINY_SCENE}


def test_a_city_index_gives_poses_in_each_querys_scene_frame(tiny_run, tmp_path):
    """The tiny scene tiled into a city 3 km east, 2 km south: the batch on the city index writes
    each pose in the query's own scene frame (the tile's translation taken off), where the scene
    map puts it (GT local maps, to a micrometre), and the answers name the scene and its city."""
    from flatlandia import localize

    ref = pd.read_parquet(tiny_run / TINY_SCENE / "maps" / "reference_map.parquet")
    q = pd.read_parquet(tiny_run / TINY_SCENE / "queries" / "queries.parquet")
    city = tiny_run / "city" / "1"
    write_one_tile_city(ref, q, city)
    on_city = batch.localize_batch(tiny_run, SPLIT, "gt", city=city / "index", progress=False).poses
    on_scene = batch.localize_batch(tiny_run, SPLIT, "gt", progress=False).poses
    assert on_city["found"].all() and (on_city["located_scene"] == TINY_SCENE).all()
    assert np.abs(on_city[["x_m", "y_m"]].to_numpy(float) - on_scene[["x_m", "y_m"]].to_numpy(float)).max() < 1e-6
    m = localize.load_map(city / "index")
    r = q[q["split"] == SPLIT].iloc[0]
    answer = localize.localize(m, localize.query_json(np.stack(r["gt_local_xy_m"]), r["classes"]), "gt", alternatives=3)
    assert (answer["scene"], answer["city"]) == (TINY_SCENE, "Flatland")
    for a in answer["alternatives"]:  # each alternative names its scene and gives its pose in that frame
        assert a["scene"] == TINY_SCENE and a["scene_x_m"] == pytest.approx(a["x_m"] - 3000.0, abs=1e-6)
    assert math.hypot(answer["scene_x_m"] - r["x_m"], answer["scene_y_m"] - r["y_m"]) < 1e-3
    assert math.hypot(answer["x_m"] - r["x_m"] - 3000.0, answer["y_m"] - r["y_m"] + 2000.0) < 1e-3


def test_fixes_per_query(tiny_run, tmp_path, capsys):
    """A fixes file gives a query its fix (the answer as `localize --gps`); a fix 400 m off rules out
    every place and the poses file says why in the reason column; a query without a row gets none."""
    q = pd.read_parquet(tiny_run / TINY_SCENE / "queries" / "queries.parquet")
    train = q[q["split"] == SPLIT].reset_index(drop=True)
    lonlat = np.column_stack([train["lon"], train["lat"]])
    far = lonlat[1] + [0.0, 400.0 / 111_200.0]  # 400 m north of the truth
    fixes = pd.DataFrame(
        {
            "scene": [TINY_SCENE, TINY_SCENE],
            "token": [train["token"][0], train["token"][1]],
            "lon": [lonlat[0, 0], far[0]],
            "lat": [lonlat[0, 1], far[1]],
            "sigma_m": [10.0, 10.0],
        }
    )
    path = tmp_path / "fixes.csv"
    fixes.to_csv(path, index=False)
    poses = tmp_path / "p.csv"
    status, out, err = _cli(
        capsys, "localize", "--batch", tiny_run, "--split", SPLIT, "--map-type", "gt", "--fixes", path, "--out", poses
    )
    assert status == 0, out + err
    p = pd.read_csv(poses, dtype=TEXT, keep_default_na=False)
    assert p["found"].tolist() == [True, False] + [True] * (len(train) - 2)
    assert p["x_m"][1] == "" and p["reason"][1].startswith("no pose: no map object within 4 sigma (40 m) of the fix")
    assert "is the fix right? lon/lat swapped?" in p["reason"][1]
    assert "beyond its reach" in err  # the fix off the map is a warning too


@pytest.mark.parametrize(
    "args, says",
    [
        (["--batch", "{tmp}", "--out", "{tmp}/p.csv"], "neither an export"),
        (["--batch", "{run}", "--out", "{tmp}/p.txt"], "a poses file is .csv or .parquet"),
        (["--batch", "{run}"], "needs --out POSES.csv"),
        (["--batch", "{run}", "--out", "{tmp}/p.csv", "--query", "q.json"], "localizes a whole split"),
        (["--batch", "{run}", "--out", "{tmp}/p.csv", "--map", "{run}/0/maps/reference_map.parquet"], "city index"),
        (["--batch", "{run}", "--out", "{tmp}/p.csv", "--fixes", "{tmp}/none.csv"], "none.csv: missing"),
        (["--map", "{run}/0/maps/reference_map.parquet", "--query", "q.json", "--fixes", "f.csv"], "for --batch"),
        (["--batch", "{run}", "--out", "{tmp}/p.csv", "--proposal", "box"], "'box' is not one of gtbb, coarse-sim"),
        (
            ["--batch", "{run}", "--out", "{tmp}/p.csv", "--proposal", "coarse-sim"],
            "coarse/sim/proposals.parquet: missing",
        ),
    ],
)
def test_bad_input_is_one_error_line_and_nothing_written(tiny_run, tmp_path, capsys, args, says):
    args = [a.format(tmp=tmp_path, run=tiny_run) for a in args]
    status, stdout, out = _cli(capsys, "localize", *args)
    assert stdout == ""  # errors on stderr: `> poses.txt` never catches one
    assert status == 1 and out.startswith("ERROR: ") and len(out.strip().splitlines()) == 1, out
    assert says in out, out
    assert not (tmp_path / "p.csv").exists() and not (tmp_path / "p.txt").exists()


# ---------------------------------------------------------------- published scenes (slow)


@pytest.mark.slow  # the published data (flat_root)
def test_batch_reproduces_the_solvers_rows_on_published_scenes(flat_root, tmp_path, capsys):
    """Scenes 7, 12 and 16 of the published data (41 test queries) laid out as the workflow writes them, with the learned
    priors of their training split (rule solver_priors' function) and the solver's whole-map runs
    (rule fine_eval's): `localize --batch` of the results folder, then `score`, gives both solver
    rows, every non-timing column; the batch of the export gives the same poses. (On the default run
    of all 20 scenes: benchmarks/bench_batch.py.)"""
    from conftest import published_scene

    from flatlandia import solver

    results = tmp_path / "results"
    cities = {"7": "Lisbon", "12": "Paris", "16": "Paris"}
    scenes = [published_scene(flat_root, s) for s in cities]
    settings = config.section_defaults("solver")
    learned = {}
    for region in ("whole", "gtbb"):  # rule solver_priors: a verifier per region
        priors = paths.within(results, paths.proposal_priors(region))  # as rule fine_eval reads them
        solver.learned_priors.fit(scenes, settings, region).write(priors)
        learned[region] = solver.LearnedPriors.read(priors)
    stats = []
    for ref, q in scenes:
        s = str(ref["scene"].iloc[0])
        lonlat = ref[["lon", "lat"]].to_numpy(float)
        meta = reference_map.frame_metadata(s, geo.frame_for(lonlat))
        reference_map.write_geoparquet(ref, meta, results / s / "maps" / "reference_map.parquet")
        files.write_parquet(q, results / s / "queries" / "queries.parquet")
        stats.append({"scene": s, "city": cities[s]})
        out = export.scene_export(s, ref, meta, q)
        for name in ("reference_map", "queries", "local_maps", "ground_truth"):
            files.write_text(export.csv_text(out[name]), results / "export" / s / f"{name}.csv")
        files.write_text(json.dumps(out["reference_geojson"]), results / "export" / s / "reference_map.geojson")
    files.write_parquet(pd.DataFrame(stats), results / score.BENCHMARK_RECORD)
    files.write_text(export.csv_text(pd.DataFrame(stats)), results / "export" / "scenes.csv")
    read = [
        (
            pd.read_parquet(results / s / "maps" / "reference_map.parquet"),
            pd.read_parquet(results / s / "queries" / "queries.parquet"),
        )
        for s in cities
    ]
    summaries = []
    settings_runs = [("depth", "whole"), ("gt", "whole"), ("depth", "gtbb")]
    for map_type, proposal in settings_runs:
        e = solver_runs.solver_errors(read, map_type, proposal, settings, learned[proposal])
        e["strategy"] = {"whole": "whole map", "gtbb": "GT-BB"}[proposal]
        summaries.append(builtin_summary(e, "solver", map_type, proposal, e["strategy"].iloc[0], read[0][0]))
        summaries[-1]["ref_map_kb"] = float(np.mean([metrics.ref_map_kb(r) for r, _ in read]))
    builtin = fine_rows.table_rows(summaries)
    for map_type, proposal in settings_runs:
        poses = tmp_path / f"{map_type}_{proposal}.csv"
        status, out, err = _cli(
            capsys, "localize", "--batch", results, "--map-type", map_type, "--proposal", proposal, "--out", poses
        )
        assert status == 0, out + err
        out_dir = tmp_path / f"{map_type}_{proposal}"
        status, out, err = _cli(capsys, "score", poses, "--name", "batch", "--out", out_dir, "--results", results)
        assert status == 0, out + err
        summary = json.loads((out_dir / f"batch_{map_type}_{proposal}" / "summary.json").read_text())
        theirs = builtin[builtin["run"] == f"solver_{map_type}_{proposal}"].reset_index(drop=True)
        assert not _row_differences(fine_rows.table_rows([summary]), theirs), (map_type, proposal)
        if proposal != "whole":
            continue
        exported = batch.localize_batch(
            results / "export", "test", map_type, learned=results / "solver" / "priors" / "whole.json", progress=False
        ).poses
        assert exported[["x_m", "y_m"]].equals(pd.read_csv(poses, dtype=TEXT)[["x_m", "y_m"]].astype(float))


def test_the_learned_priors_are_those_rule_fine_eval_reads(tmp_path):
    """The learned priors a batch reads for a proposal (paths.proposal_priors) are those of the solver's
    fine_eval job on that proposal, as Snakemake resolves its input."""
    from conftest import REPO

    from flatlandia import vocabulary
    from flatlandia.plumbing import debug

    tiny = [REPO / "config" / "test" / "tiny.yaml"]
    for proposal in (vocabulary.WHOLE, vocabulary.GTBB, "coarse-simtrip"):
        job = debug.mock_snakemake(
            "fine_eval", workdir=tmp_path, configfiles=tiny, method="solver", map_type="depth", proposal=proposal
        )
        assert job.input.solver_priors == paths.proposal_priors(proposal), proposal


def test_a_progress_bar_on_a_terminal_only_and_none_without_tqdm(tiny_run, monkeypatch, capsys):
    """The batch draws tqdm's bar on stderr when stderr is a terminal, nothing when it is not (a log),
    and runs without one where tqdm is not installed (the localizer alone needs no workflow extras)."""
    import sys

    batch.localize_batch(tiny_run, SPLIT, "gt")
    assert capsys.readouterr().err == ""  # not a terminal
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    batch.localize_batch(tiny_run, SPLIT, "gt")
    err = capsys.readouterr().err
    assert "localize: 100%" in err and "10/10" in err, err
    monkeypatch.setitem(sys.modules, "tqdm", None)  # import tqdm raises ImportError
    poses = batch.localize_batch(tiny_run, SPLIT, "gt").poses
    assert poses["found"].all() and capsys.readouterr().err == ""
