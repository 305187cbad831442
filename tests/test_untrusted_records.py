"""Untrusted inputs, fourth pass (issue 42, findings 8 and 9): typed records and the reads that went
around the doors. EXIF descriptions through the JSON door (one bad photo dropped, not the scene);
metadata.csv altitudes and headings in the geotag's ranges; priors and calibration JSON checked field
by field (types and finite, meaningful ranges); ``flatlandia score --results`` reading maps and
queries through the doors of ``flatlandia localize`` (a forged frame is the map's error; a map across
the antimeridian scores right poses right; a NaN truth is refused); ``--batch`` reading an export's
ground_truth.csv and local maps through the same door. Hand-made small files: fast."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import TINY_SCENE
from PIL import ExifTags, Image
from tiny_results import tiny_scene

from flatlandia import cli, geo, score, solver
from flatlandia.data import export, reference_map
from flatlandia.images import image_audit
from flatlandia.localize import batch, maps
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError
from flatlandia.solver.calibration import Calibration, Logistic


def _raises(path, call, *says: str) -> str:
    """``call()`` raises one InputError naming ``path`` and saying each of ``says``; its message."""
    with pytest.raises(InputError) as e:
        call()
    assert e.value.path == str(path), (e.value.path, str(path))
    for s in says:
        assert s in e.value.problem, (s, e.value.problem)
    return e.value.problem


# ----------------------------------------------------------------------------- photos


def test_a_hostile_exif_description_drops_its_photo_not_the_scene(tmp_path):
    """20,000 nested brackets (RecursionError) or a 5,000-digit number (ValueError) in one photo's
    ImageDescription stopped the whole scene's image_audit."""
    img = Image.new("RGB", (64, 64), (120, 130, 140))
    for name, desc in (
        ("deep.jpg", '{"MAPCompassHeading": ' + "[" * 20_000 + "]" * 20_000 + "}"),
        ("digits.jpg", '{"MAPCompassHeading": {"TrueHeading": ' + "9" * 5000 + "}}"),
    ):
        ex = Image.Exif()
        ex[ExifTags.Base.ImageDescription] = desc
        img.save(tmp_path / name, exif=ex)
    img.save(tmp_path / "plain.jpg")
    table = image_audit.audit_table(tmp_path, dedup_threshold=0.0, missing_gps="keep").set_index("name")
    assert "ImageDescription" in table.loc["deep.jpg", "drop_reason"], table.loc["deep.jpg", "drop_reason"]
    assert "nested deeper" in table.loc["deep.jpg", "drop_reason"]
    assert "impossible geotag" in table.loc["digits.jpg", "drop_reason"]  # a heading of 10**5000: inf
    assert table.loc["plain.jpg", "kept"] and not table.loc["deep.jpg", "kept"]


def test_a_metadata_csv_altitude_or_heading_of_1e308_is_refused_as_exifs_are(tmp_path):
    csv = tmp_path / "metadata.csv"
    for column in ("alt", "heading"):
        csv.write_text(f"name,lat,lon,{column}\na.jpg,55.7,13.2,1e308\n")
        lo, hi = image_audit.GEOTAG_RANGES[column]
        _raises(
            csv, lambda: image_audit.read_metadata_csv(csv, ["a.jpg"]), f"line 2, column {column}", f"[{lo:g}, {hi:g}]"
        )
    csv.write_text("name,lat,lon,alt,heading\na.jpg,55.7,13.2,12.5,359\n")
    assert image_audit.read_metadata_csv(csv, ["a.jpg"]).loc["a.jpg", "alt"] == 12.5


# ----------------------------------------------------------------------------- priors and calibration


def _priors() -> dict:
    cal = Calibration(Logistic(-0.5, (0.3, 0.2, 0.0, 1.0), 200), None)
    return solver.LearnedPriors((3.0, 0.4), None, None, cal).to_dict()


def test_priors_and_calibration_are_checked_field_by_field(tmp_path):
    """``"calibration": [1]`` or a text was an AttributeError in localize and fine_eval; weights
    "1234" were read as the digits 1, 2, 3, 4 and weights of 1e308 accepted (both change every
    answer's status and probability); ``{}`` was read as "no priors"."""
    good = _priors()
    frame = good["calibration"]["frame"]
    nf = len(good["features"])
    cases = {
        "list": ({**good, "calibration": [1]}, "calibration must be a JSON object"),
        "text": ({**good, "calibration": "calibrated"}, "calibration must be a JSON object"),
        "digits": (
            {**good, "calibration": {**good["calibration"], "frame": {**frame, "weights": "1234"}}},
            "calibration frame weights must be a list",
        ),
        "huge": (
            {**good, "calibration": {**good["calibration"], "frame": {**frame, "weights": [1e308, 0, 0, 0]}}},
            "calibration frame weights[0] must be a finite number in [-1000, 1000]",
        ),
        "intercept": (
            {**good, "calibration": {**good["calibration"], "frame": {**frame, "intercept": "0"}}},
            "calibration frame intercept must be a finite number",
        ),
        "answers": (
            {**good, "calibration": {**good["calibration"], "frame": {**frame, "answers": 1.5}}},
            "calibration frame answers must be an integer",
        ),
        "map_size": ({**good, "calibration": {**good["calibration"], "map_size": [1]}}, "calibration map_size"),
        "likelihood": ({**good, "likelihood": "1234"}, "likelihood must be a JSON object"),
        "verifier": (
            {**good, "verifier": {"weights": [1e308] * nf, "mean": [0.0] * nf, "scale": [1.0] * nf}},
            "verifier weights[0] must be a finite number in [-1000, 1000]",
        ),
        "empty": ({}, "format 1 (no 'format' key"),
        "format": ({**good, "format": 99}, "a solver priors file of format 99, this solver reads format 2"),
        "absent": ({"format": 2}, "lack scale_prior"),
    }
    for name, (value, says) in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(value))
        _raises(path, lambda path=path: solver.LearnedPriors.read(path), says)
    path = tmp_path / "good.json"
    path.write_text(json.dumps(good))
    assert solver.LearnedPriors.read(path).calibration.frame.weights == (0.3, 0.2, 0.0, 1.0)


def test_a_likelihood_model_is_checked_field_by_field(tmp_path):
    from flatlandia.solver.likelihood import LikelihoodModel

    nb, na, nk = 7, 6, 42
    model = LikelihoodModel(
        55.0, 95.0, -2.0, (0.1,) * nk, (0.2,) * nb, (0.3,) * na, 7.3, 0.1, -2.0,
        (0.1,) * nk, (0.2,) * nb, (0.3,) * na, 20,
    )  # fmt: skip
    doc = model.to_dict()
    assert LikelihoodModel.from_dict(json.loads(json.dumps(doc)), "p.json") == model
    for change, says in (
        ({"share_w": 1e308}, "likelihood share_w must be a finite number in [-1000, 1000]"),
        ({"cls_logit": "1234"}, "likelihood cls_logit must be a list of 42 numbers"),
        ({"max_range_m": [95.0]}, "likelihood max_range_m must be a finite number"),
        ({"in_view": "many"}, "likelihood in_view must be an integer"),
    ):
        _raises("p.json", lambda change=change: LikelihoodModel.from_dict({**doc, **change}, "p.json"), says)


# ----------------------------------------------------------------------------- score --results


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """The tiny scene's results folder as scoring reads it: its reference map, queries and the
    benchmark record."""
    root = tmp_path_factory.mktemp("records") / "results"
    tiny_scene().write(root)
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE]}), root / score.BENCHMARK_RECORD)
    return root


def _copy(results, tmp_path):
    out = tmp_path / "results"
    shutil.copytree(results, out)
    return out, out / TINY_SCENE / "maps" / "reference_map.parquet", out / TINY_SCENE / "queries" / "queries.parquet"


def _with_metadata(path, text: str) -> None:
    table = pq.read_table(path)
    md = dict(table.schema.metadata or {})
    md[b"flatlandia"] = text.encode()
    pq.write_table(table.replace_schema_metadata(md), path)


def test_score_reads_maps_and_queries_through_the_doors(results, tmp_path):
    """`score --results` read maps and queries outside the map door: lon0 "abc" (a ValueError), NaN
    (a NaN frame), a queries table without its split column (a KeyError later), a FIFO."""
    meta = files.read_parquet_metadata(results / TINY_SCENE / "maps" / "reference_map.parquet")
    for lon0, says in (('"abc"', "metadata lon0 must be a finite number"), ("NaN", "metadata lon0 must be a finite")):
        root, ref, _ = _copy(results, tmp_path / lon0.strip('"'))
        _with_metadata(ref, json.dumps({**meta, "lon0": "LON0"}).replace('"LON0"', lon0))
        _raises(ref, lambda root=root: score.results_scenes(root), says)
    root, _, q = _copy(results, tmp_path / "split")
    pd.read_parquet(q).drop(columns="split").to_parquet(q)
    _raises(q, lambda: score.results_scenes(root), "missing column(s) split")
    root, _, q = _copy(results, tmp_path / "fifo")
    q.unlink()
    os.mkfifo(q)
    _raises(q, lambda: score.results_scenes(root), "not a regular file")


def test_a_forged_frame_is_the_maps_error_and_a_map_across_the_antimeridian_scores_right(results, tmp_path, capsys):
    """A reference map whose lon0 says 170 (its objects are at lon 11) made right poses '9281 km
    outside the scene'; a genuine map across the antimeridian must score right poses right (and
    load as a map: its objects lie beside its origin, not a turn away)."""
    meta = files.read_parquet_metadata(results / TINY_SCENE / "maps" / "reference_map.parquet")
    root, ref, _ = _copy(results, tmp_path / "forged")
    _with_metadata(ref, json.dumps({**meta, "lon0": 170.0}))
    truth = pd.read_parquet(results / TINY_SCENE / "queries" / "queries.parquet")
    truth = truth[truth["split"] == "train"]
    poses = tmp_path / "poses.csv"
    pd.DataFrame(
        {"scene": truth["scene"], "token": truth["token"], "lon": truth["lon"], "lat": truth["lat"],
         "heading_deg": 90 - truth["theta_deg"]}
    ).to_csv(poses, index=False)  # fmt: skip
    rc = cli.main(
        [
            "score",
            str(poses),
            "--name",
            "mine",
            "--split",
            "train",
            "--results",
            str(root),
            "--out",
            str(tmp_path / "o"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith(f"ERROR: {ref}: "), err
    assert "km from its objects" in err[0] and "outside the scene" not in err[0]

    # the tiny scene moved onto the antimeridian: the same metres, its lon/lat in a frame at lon0 179.9999
    tiny = tiny_scene()
    frame = geo.MetricFrame(179.9999, tiny.meta["lat0"])
    ref_t, q_t = tiny.ref, tiny.queries
    ref_t[["lon", "lat"]] = frame.to_lonlat(ref_t[["x_m", "y_m"]].to_numpy(float))
    q_t[["lon", "lat"]] = frame.to_lonlat(q_t[["x_m", "y_m"]].to_numpy(float))
    assert (ref_t["lon"] < 0).any() and (ref_t["lon"] > 0).any()  # across it
    meta = reference_map.frame_metadata(TINY_SCENE, frame)
    far = tmp_path / "antimeridian"
    reference_map.write_geoparquet(ref_t, meta, far / TINY_SCENE / "maps" / "reference_map.parquet")
    files.write_parquet(q_t, far / TINY_SCENE / "queries" / "queries.parquet", tiny.queries_meta)
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE]}), far / score.BENCHMARK_RECORD)
    train = q_t[q_t["split"] == "train"]
    pd.DataFrame(
        {"scene": train["scene"], "token": train["token"], "lon": train["lon"], "lat": train["lat"],
         "heading_deg": 90 - train["theta_deg"]}
    ).to_csv(poses, index=False)  # fmt: skip
    scores = score.score_file(poses, "mine", far, split="train")
    errors = scores.runs[0].errors
    assert len(errors) == len(train) and errors["error_m"].max() < 1e-3, errors["error_m"]
    assert not [w for w in scores.warnings if "outside" in w], scores.warnings
    m = maps.load_map(far / TINY_SCENE / "maps" / "reference_map.parquet", learned=None)  # the localize door too
    assert np.abs(m.xy - ref_t[["x_m", "y_m"]].to_numpy(float)).max() < 1e-6
    geojson = tmp_path / "antimeridian.geojson"  # a map without a frame: centred on the antimeridian
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [lon, lat]},
            "properties": {"class_id": int(c)},
        }
        for lon, lat, c in zip(ref_t["lon"], ref_t["lat"], ref_t["class_id"])
    ]
    geojson.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    span = np.ptp(maps.load_map(geojson, learned=None).xy, axis=0)
    assert (span < 200).all(), span  # metres of a scene, not of half the Earth


def test_a_nan_truth_is_refused_naming_the_file_and_the_query(results, tmp_path):
    """A NaN ground truth was scored as a failure without a word (every error and the denominator
    changed): it is an InputError naming the file, the query and the column."""
    root, _, q = _copy(results, tmp_path)
    t = pd.read_parquet(q)
    t.loc[2, "x_m"] = np.nan
    t.to_parquet(q)
    _raises(q, lambda: score.results_scenes(root), f"row 3 (token '{t.loc[2, 'token']}'), column x_m", "not a finite")


# ----------------------------------------------------------------------------- localize --batch


def test_the_batch_checks_an_exports_ground_truth_against_its_map(results, tmp_path):
    """`--batch` read the export's ground_truth.csv unchecked: a 20-digit object id (OverflowError),
    NaN or 1e300 x_m, object ids 99999 or -5 (none of the map's) were used or a traceback."""
    ref = pd.read_parquet(results / TINY_SCENE / "maps" / "reference_map.parquet")
    tiny = tiny_scene()
    out = export.scene_export(TINY_SCENE, ref, tiny.meta, tiny.queries)
    folder = tmp_path / TINY_SCENE
    files.write_text(json.dumps(out["reference_geojson"]), folder / "reference_map.geojson")
    gt = out["ground_truth"]
    src = batch.Source("export", tmp_path, [TINY_SCENE])
    path = folder / "ground_truth.csv"
    cases = [
        ("x_m", "nan", "row 1 (token", "column x_m: nan is not a finite number"),
        ("y_m", "1e300", "row 1 (token", "column y_m: 1e+300 is not a finite number within 1e+06"),
        ("theta_deg", "１", "row 1, column theta_deg: '１' is not a number"),  # a full-width digit
        ("matched_obj_idx", "12345678901234567890", "row 1, column matched_obj_idx", "at most 18 digits"),
        ("matched_obj_idx", "99999 3", "column ref_idx: object id(s) [99999] are none of the map's objects"),
        ("matched_obj_idx", "-5", "object id(s) [-5] are none"),
    ]
    for column, value, *says in cases:
        bad = gt.astype({column: object})
        bad.loc[0, column] = value
        files.write_text(export.csv_text(bad), path)
        _raises(path, lambda: src.scene_map(TINY_SCENE, None), *says)
    files.write_text(export.csv_text(gt), path)
    assert src.scene_map(TINY_SCENE, None).cameras == int((gt["split"] == "train").sum())


def test_the_batch_reads_local_map_cells_as_plain_numbers(tmp_path):
    """local_maps.csv: a 20-digit k or class id was an OverflowError; full-width digits were numbers."""
    scene = tmp_path / "0"
    scene.mkdir()
    (scene / "queries.csv").write_text("token,split\nq1,test\n")
    for k, x, says in (("12345678901234567890", "1.0", "column k"), ("0", "１", "column x: '１' is not a number")):
        rows = [f"q1,gt,{k},24,{x},1.0", "q1,gt,1,24,2.0,1.0", "q1,gt,2,24,3.0,1.0"]
        (scene / "local_maps.csv").write_text("token,map_type,k,class_id,x,y\n" + "\n".join(rows) + "\n")
        _raises(scene / "local_maps.csv", lambda: batch._export_queries(tmp_path, "0", "test", "gt"), "row 1", says)
