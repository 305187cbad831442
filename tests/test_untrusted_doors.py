"""Untrusted inputs, third pass, the workflow's other doors: a fetch replaces only what the run's own
record says it fetched (finding 2: a planted marker deleted a folder of photos), `flatlandia debug`
takes only the wildcard values a run could give (3), the export's CSVs carry no spreadsheet formula
(4), the audit reads only well-formed records and hashes only the run's own files (5, 8), NaN in
the published transforms or a checkpoint and a checkpoint asking for 10 TB are refused (6, 8),
config values nested too deep are one line (8), data text in figures is no mathtext (9), impossible
EXIF geotags are a drop reason (10). Fast, on files built here and the tiny scene; one slow test
checks every published token against the CSV rule."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import REPO, TINY_ROOT, TINY_SCENE
from PIL import ExifTags, Image
from PIL.TiffImagePlugin import IFDRational
from tiny_results import tiny_scene
from zip_archives import make_zip

from flatlandia import checkpoints, cli, config
from flatlandia.classes import CLASSES
from flatlandia.data import export, fetch, published, reference_map
from flatlandia.fine import models
from flatlandia.images import image_audit
from flatlandia.objects import audit
from flatlandia.plumbing import escape, files, rule_log
from flatlandia.plumbing.errors import InputError
from flatlandia.report import figures
from flatlandia.viewer import query_figures, scene_view


def tree(root: Path) -> set[str]:
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        out |= {str(Path(dirpath, n).relative_to(root)) for n in dirnames + filenames}
    return out


@pytest.fixture(scope="module")
def tiny() -> dict:
    """The tiny scene's reference map (table, metadata) and queries, as rules reference_map and queries make them."""
    tiny = tiny_scene()
    return {"ref": tiny.ref, "meta": tiny.meta, "queries": tiny.queries}


# ----------------------------------------------------------------------------- 2. fetch


def test_a_planted_fetch_marker_no_longer_lets_a_fetch_delete_a_folder(tmp_path, monkeypatch):
    """A folder of photos holding a forged .flatlandia-fetch ({"url": "x"}) was replaced when
    fetch.dest named it: its photos were deleted. Only the run's own record allows a replacement."""
    run = tmp_path / "run"
    photos = run / "resources" / "my_photos"  # where a fetch may write: below resources/
    photos.mkdir(parents=True)
    (photos / "01.jpg").write_bytes(b"my photo")
    (photos / fetch.FETCH_MARKER).write_text(json.dumps({"url": "x"}))
    archive = make_zip(tmp_path / "a.zip", {"top/data/local_maps.json": b"{}", "top/imgs/1.jpg": b"1"})
    scenes = pd.DataFrame({"scene": ["0"], "city": ["x"], "name": ["y"]})
    before = tree(tmp_path)
    monkeypatch.chdir(run)  # the working folder
    with pytest.raises(fetch.FetchError, match="a folder not written by a fetch of this run"):
        fetch.fetch_flatlandia(photos, scenes, url=archive.as_uri(), timeout_s=5)
    with pytest.raises(fetch.FetchError, match="a folder not written by a fetch of this run"):
        fetch.fetch_images(archive.as_uri(), "imgs", photos, timeout_s=5)
    assert tree(tmp_path) == before and (photos / "01.jpg").read_bytes() == b"my photo"


def test_a_dest_outside_the_working_folder_is_refused_unless_it_is_the_data_folder(tmp_path):
    """fetch.dest could be any absolute path outside the run."""
    run, elsewhere = tmp_path / "run", tmp_path / "elsewhere" / "data"
    run.mkdir()
    archive = make_zip(tmp_path / "a.zip", {"top/data/local_maps.json": b"{}"})
    scenes = pd.DataFrame({"scene": ["0"], "city": ["x"], "name": ["y"]})
    with pytest.raises(fetch.FetchError, match="outside the working folder"):
        fetch.fetch_flatlandia(elsewhere, scenes, url=archive.as_uri(), timeout_s=5, workdir=run)
    assert not elsewhere.exists()
    got = fetch.fetch_flatlandia(
        elsewhere, scenes, url=archive.as_uri(), timeout_s=5, workdir=run, data_folder=elsewhere
    )
    assert (got / "local_maps.json").exists() and fetch.fetched_before(elsewhere, run)
    assert json.loads((run / fetch.FETCH_STATE).read_text())[str(elsewhere.resolve())]["url"] == archive.as_uri()


def test_a_file_source_that_is_a_pipe_is_refused_at_once(tmp_path):
    fifo = tmp_path / "archive.zip"
    os.mkfifo(fifo)
    t0 = time.monotonic()
    with pytest.raises(fetch.FetchError, match="not a regular file"):
        fetch.fetch_images(fifo.as_uri(), "imgs", tmp_path / "resources/imgs", timeout_s=5, workdir=tmp_path)
    assert time.monotonic() - t0 < 5 and not (tmp_path / "resources/imgs").exists()


# ----------------------------------------------------------------------------- 3. flatlandia debug


def _debug(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    run = tmp_path / "a" / "b" / "c" / "run"
    run.mkdir(parents=True, exist_ok=True)
    return subprocess.run(
        [sys.executable, "-m", "flatlandia.cli", "debug", *args, "-d", str(run), "--show"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=run,
    )


@pytest.mark.parametrize(
    "args, says",
    [
        (["solver_priors", "region=../../../../x/pwn"], "wildcard region='../../../../x/pwn' is refused: holds '/'"),
        (["solver_priors", "region=nowhere"], "wildcard region='nowhere' is not one rule solver_priors takes"),
        (["reference_map", "scene=999"], "wildcard scene='999' is not one rule reference_map takes"),
    ],
)
def test_debug_takes_only_wildcards_a_run_could_give(tmp_path, args, says):
    """region=../../../../x/pwn wrote outside the working folder; an unknown scene was a traceback."""
    before = tree(tmp_path)
    res = _debug(tmp_path, *args)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("ERROR:")]
    assert res.returncode == 2 and errors == [f"ERROR: {says}" + errors[0].split(says, 1)[1]], (
        res.stdout + res.stderr[-2000:]
    )
    assert "Traceback" not in res.stderr and not res.stdout.startswith("rule ")  # the job was never built
    assert tree(tmp_path) - before <= {"a", "a/b", "a/b/c", "a/b/c/run"} | {
        p for p in tree(tmp_path) if p.startswith("a/b/c/run/")
    }


# ----------------------------------------------------------------------------- 4. spreadsheet formulas


HOSTILE = ['=HYPERLINK("http://x","y")', "+cmd|' /C calc'!A0", "@SUM(1+1)", "-2+3", "\t=1", "-cmd|x"]


def test_no_cell_of_the_export_runs_in_a_spreadsheet(tiny, tmp_path):
    """Tokens +cmd|calc or =HYPERLINK(...) in local_maps.json and a city =HYPERLINK(...) came out as
    they were in every CSV of the export."""
    q = tiny["queries"].copy()
    tokens = HOSTILE + ["-AB21Af_LPev08UY_96ptQ"]
    q["token"] = [tokens[k % len(tokens)] + ("" if k < len(tokens) else str(k)) for k in range(len(q))]
    out = export.scene_export(TINY_SCENE, tiny["ref"], tiny["meta"], q)
    index = export.index_export(
        [{"scene": TINY_SCENE, "city": HOSTILE[0], "ref": tiny["ref"], "meta": tiny["meta"], "queries": q}], []
    )
    texts = {name: export.csv_text(out[name]) for name in ("queries", "local_maps", "proposals", "ground_truth")}
    texts |= {name: export.csv_text(index[name]) for name in ("scenes", "template", "classes")}
    runs = ("=", "+", "@", "\t", "\r")
    for name, text in texts.items():
        files.write_text(text, tmp_path / f"{name}.csv")
        back = pd.read_csv(tmp_path / f"{name}.csv", dtype=str, keep_default_na=False)
        cells = [c for col in back.columns for c in back[col]] + list(back.columns)
        plain = [c for c in cells if escape._PLAIN_DASHED.fullmatch(c) or escape._PROJ.fullmatch(c)]  # words, crs
        assert not [c for c in set(cells) - set(plain) if c.startswith((*runs, "-"))], name
        if name in ("queries", "local_maps"):  # every split: every token
            assert "-AB21Af_LPev08UY_96ptQ" in set(back["token"])  # a published token passes unchanged
        if "token" in back.columns:  # and every value reads back
            assert {escape.csv_cell_read(t) for t in back["token"]} <= set(q["token"]), name
    scenes = pd.read_csv(tmp_path / "scenes.csv", dtype=str)
    assert scenes["city"].iloc[0] == "'" + HOSTILE[0] and scenes["crs"].iloc[0] == tiny["meta"]["crs"]


@pytest.mark.slow
def test_every_published_token_and_city_passes_the_csv_rule_unchanged(flat_root, all_local_maps):
    tokens = [t for s in all_local_maps.values() for t in s] + [
        t for f in flat_root.glob("maps/*/tokens.txt") for t in f.read_text().split()
    ]
    sheet = pd.read_csv(REPO / "config" / "scenes.tsv", sep="\t", dtype=str, keep_default_na=False)
    values = tokens + sheet["city"].tolist() + sheet["name"].tolist() + CLASSES
    assert len(tokens) > 2000 and any(t.startswith("-") for t in tokens)
    assert [v for v in values if escape.csv_cell(v) != v] == []


# ----------------------------------------------------------------------------- 5, 8. the audit


def _record(rule: str, outputs: dict, **over) -> dict:
    rec = {
        "rule": rule,
        "wildcards": {},
        "inputs": {},
        "outputs": {k: {"sha256": v, "bytes": 1} for k, v in outputs.items()},
        "config_hash": "0",
        "package_version": "0",
        "git_commit": "x",
        "finished_at": "now",
    }
    return {**rec, **over}


def test_the_audit_skips_broken_records_and_hashes_only_the_runs_own_files(tmp_path, monkeypatch, capsys):
    """A record naming / or a 40 GB file elsewhere was hashed; an invalid record stopped every audit."""
    run = tmp_path / "run"
    prov = run / "logs" / "provenance"
    (run / "results").mkdir(parents=True)
    (run / "results" / "a.txt").write_text("a")
    outside = tmp_path / "big.bin"
    with open(outside, "wb") as f:
        f.truncate(40 * 10**9)  # sparse: 40 GB that nothing may read
    digest = files.sha256(run / "results" / "a.txt")
    recs = {
        "good/all.json": _record("good", {"results/a.txt": digest}),
        "root/all.json": _record("root", {"/": "0"}),
        "big/all.json": _record("big", {str(outside): "0"}),
        "up/all.json": _record("up", {"../big.bin": "0"}),
        "list/all.json": {**_record("list", {}), "outputs": ["results/a.txt"]},
        "norule/all.json": {k: v for k, v in _record("x", {"results/a.txt": digest}).items() if k != "rule"},
        "config/all.json": _record("cfg", {"results/a.txt": digest}, config_id="../../../etc/passwd"),
    }
    for name, rec in recs.items():
        (prov / name).parent.mkdir(parents=True, exist_ok=True)
        (prov / name).write_text(json.dumps(rec))
    (prov / "broken").mkdir()
    (prov / "broken" / "all.json").write_text("{not json")
    (run / "results" / "link").symlink_to("/", target_is_directory=True)
    (prov / "link").mkdir()
    (prov / "link" / "all.json").write_text(json.dumps(_record("link", {"results/link": "0"})))
    monkeypatch.chdir(run)
    t0 = time.monotonic()
    rc = cli.main(["audit", "--check"])
    got = capsys.readouterr()
    lines = got.out.splitlines()
    assert time.monotonic() - t0 < 30, "the audit read what it must not"
    assert rc == 0 and lines[-1] == "all 1 recorded artifacts match their records", lines
    warnings = [ln for ln in got.err.splitlines() if ln.startswith("WARNING: ")]
    for name in ("root", "big", "up", "list", "norule", "config", "broken"):
        assert any(f"{name}/all.json" in w for w in warnings), (name, warnings)
    assert any("results/link" in w and "outside the run's folder" in w for w in warnings), warnings
    assert rc == 0 and cli.main(["audit", "results/a.txt"]) == 0
    assert "rule: good" in capsys.readouterr().out


# ----------------------------------------------------------------------------- 6, 8. transforms and checkpoints


@pytest.mark.parametrize("value", [float("nan"), float("-inf")])
def test_nan_in_the_published_transforms_is_refused(tmp_path, value):
    """A NaN rotation wrote objects.parquet with NaN/-inf lon/lat (rc 0), then a CRSError traceback."""
    t = json.loads((TINY_ROOT / "maps" / TINY_SCENE / "transformations.json").read_text())
    t["to_mapillary"]["rotation"][0][0] = value
    path = tmp_path / "transformations.json"
    path.write_text(json.dumps(t))  # written as NaN / -Infinity, as Python's json does
    with pytest.raises(InputError, match="to_mapillary.rotation holds NaN or inf"):
        published.read_transformations(path)
    t = json.loads((TINY_ROOT / "maps" / TINY_SCENE / "transformations.json").read_text())
    t["to_principal_plane"][0] = [5.0, 0.0, 0.0]
    path.write_text(json.dumps(t))
    with pytest.raises(InputError, match="to_principal_plane is not a rotation or a reflection"):
        published.read_transformations(path)


def _checkpoint(tmp_path: Path, state: dict, meta: str | None = None, **cfg_over) -> Path:
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    path = tmp_path / "ck.pt"
    text = meta if meta is not None else json.dumps({"config": {**cfg.to_dict(), **cfg_over}})
    torch.save({"format": checkpoints.FORMAT, "state_dict": state, "meta": text}, path)
    return path


def _load_error(path: Path, capsys) -> str:
    def main(smk, log):  # as a rule script loads it
        checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)

    with pytest.raises(SystemExit):
        rule_log.run(main, SimpleNamespace(log=[]))
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and errors[0].startswith(f"ERROR: {path}: ") and "Traceback" not in err, err
    return errors[0]


def test_a_checkpoint_with_nan_weights_is_refused(tmp_path, capsys):
    state = models.build_model(models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)).state_dict()
    key = next(k for k, v in state.items() if v.is_floating_point())
    state[key] = torch.full_like(state[key], float("nan"))
    assert f"the weights {key} hold NaN or inf" in _load_error(_checkpoint(tmp_path, state), capsys)


def test_a_checkpoint_asking_for_terabytes_or_nested_too_deep_is_one_line(tmp_path, capsys):
    """hidden=200000, heads=64 tried to allocate 10 TB; meta nested 100,000 deep was a RecursionError."""
    state = models.build_model(models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)).state_dict()
    t0 = time.process_time()
    line = _load_error(_checkpoint(tmp_path, state, hidden=200000, heads=64), capsys)
    assert "the weights do not fit the model its config describes" in line and time.process_time() - t0 < 10
    line = _load_error(_checkpoint(tmp_path, state, meta="[" * 100_000 + "]" * 100_000), capsys)
    assert "nested deeper than 32 levels" in line


def test_a_config_value_nested_too_deep_is_one_line():
    deep = value = {}
    for _ in range(500):
        value["a"] = {}
        value = value["a"]
    with pytest.raises(config.ConfigError, match="'solver': the value nests deeper than 16 levels"):
        config.resolve({"solver": {"top_k": deep}})


# ----------------------------------------------------------------------------- 9. mathtext


SECRET = r"$\input{secret.tex}$"


def test_data_text_in_figures_is_drawn_as_text_not_mathtext(tiny, tmp_path):
    """A scene sheet city of $\\input{secret.tex}$ crashed plot_reference_map (mathtext ValueError);
    query figures put raw tokens, which may hold '$', in their titles."""
    ref, q = tiny["ref"], tiny["queries"]
    reference_map.plot_reference_map(
        ref, q, tmp_path / "map.png", f"scene 0 ({SECRET}): 30 objects", axes=(SECRET, "y")
    )
    xy = ref[["x_m", "y_m"]].to_numpy(float)
    audit.plot_audit_grid([(f"scene {SECRET}", xy, xy)], tmp_path / "grid.png")
    cam = q[["x_m", "y_m"]].to_numpy(float)[0]
    figures.plot_score_heatmap(
        ref, {SECRET: np.arange(len(ref), dtype=float)}, np.array([0]), cam, 10.0, tmp_path / "h.png", SECRET
    )
    hist = pd.DataFrame({"epoch": [0, 1], "train_loss": [1.0, 0.5]})
    figures.plot_training_curves({SECRET: hist}, tmp_path / "curves.png")
    q2 = q.assign(token=[f"{SECRET}{k}" for k in range(len(q))])
    view = scene_view.scene_view(SECRET, ref, q2, {}, axes=(SECRET, "y $x$"))
    fig = query_figures.query_figure(view, view.queries[0])
    fig.savefig(tmp_path / "query.png")
    figures.pyplot().close(fig)
    fig = query_figures.worst_figure(view)
    fig.savefig(tmp_path / "worst.png")
    figures.pyplot().close(fig)
    for name in ("map", "grid", "h", "curves", "query", "worst"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000, name


# ----------------------------------------------------------------------------- 10. EXIF geotags


def test_an_impossible_exif_geotag_is_a_drop_reason(tmp_path):
    """EXIF latitude 1e9 or a heading of 1e308 were kept (or ignored) silently."""
    ok = Image.new("RGB", (64, 64), (120, 130, 140))
    ex = Image.Exif()
    gps = ex.get_ifd(ExifTags.IFD.GPSInfo)
    gps[ExifTags.GPS.GPSLatitudeRef] = "N"
    gps[ExifTags.GPS.GPSLatitude] = (IFDRational(1e9), IFDRational(0), IFDRational(0))
    gps[ExifTags.GPS.GPSLongitudeRef] = "E"
    gps[ExifTags.GPS.GPSLongitude] = (IFDRational(13), IFDRational(11), IFDRational(0))
    ok.save(tmp_path / "lat.jpg", exif=ex)
    ex = Image.Exif()
    ex[ExifTags.Base.ImageDescription] = json.dumps(
        {"MAPLatitude": 55.7, "MAPLongitude": 13.2, "MAPCompassHeading": {"TrueHeading": 1e308}}
    )
    ok.save(tmp_path / "heading.jpg", exif=ex)
    ok.save(tmp_path / "plain.jpg")
    df = image_audit.read_folder_metadata(tmp_path).set_index("name")
    assert df.loc["lat.jpg", "problem"].startswith("impossible geotag in its EXIF (lat 1e+09 outside [-90, 90])")
    assert "heading 1e+308 outside [-360, 360]" in df.loc["heading.jpg", "problem"]
    assert df.loc["heading.jpg", "lat"] == 55.7 and not isinstance(df.loc["plain.jpg", "problem"], str)
    (tmp_path / "metadata.csv").write_text("name,lat,lon\nlat.jpg,55.7,13.18\n")  # metadata.csv gives the value
    df = image_audit.read_folder_metadata(tmp_path).set_index("name")
    assert not isinstance(df.loc["lat.jpg", "problem"], str) and df.loc["lat.jpg", "lat"] == 55.7
    table = image_audit.audit_table(tmp_path, dedup_threshold=0.0)
    assert table.set_index("name").loc["heading.jpg", "drop_reason"].startswith("impossible geotag")


# ----------------------------------------------------------------------------- 5. the batch's export CSVs


def test_the_batch_reads_an_exports_csvs_within_bounds(tmp_path):
    """`localize --batch` (issue 36) reads a user's export: regular files within MAX_CSV_BYTES, local
    maps of finite coordinates, at most MAX_QUERY_OBJECTS objects."""
    from flatlandia.localize import batch
    from flatlandia.plumbing import validate

    scene = tmp_path / "0"
    scene.mkdir()
    os.mkfifo(scene / "queries.csv")
    with pytest.raises(InputError, match="is not a regular file"):
        batch._export_queries(tmp_path, "0", "test", "gt")
    (scene / "queries.csv").unlink()
    with open(scene / "queries.csv", "wb") as f:
        f.truncate(validate.MAX_CSV_BYTES + 1)
    with pytest.raises(InputError, match="MAX_CSV_BYTES"):
        batch._export_queries(tmp_path, "0", "test", "gt")
    (scene / "queries.csv").write_text("token,split,n_objects\nq1,test,3\n")
    rows = [f"q1,test,gt,{k},24,object--street-light,{x},1.0" for k, x in enumerate(["1.0", "2.0", "nan"])]
    (scene / "local_maps.csv").write_text("token,split,map_type,k,class_id,class,x,y\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match="query 'q1': x, y must be finite numbers"):
        batch._export_queries(tmp_path, "0", "test", "gt")
    many = [f"q1,test,gt,{k},24,object--street-light,{1.0 + k},1.0" for k in range(validate.MAX_QUERY_OBJECTS + 1)]
    (scene / "local_maps.csv").write_text("token,split,map_type,k,class_id,class,x,y\n" + "\n".join(many) + "\n")
    with pytest.raises(InputError, match="101 objects in query 'q1'"):
        batch._export_queries(tmp_path, "0", "test", "gt")
