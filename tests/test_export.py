"""The benchmark exported as plain files (flatlandia.data.export, target `export`): the CSVs read back
equal the Parquet values, the ground truth places each GT local map on its matched reference
objects, theta_deg and heading_deg agree, the proposals are the workflow's. On the tiny scene
(fast lane), a dry run of the target on it, and one real `snakemake export` on two scenes (slow)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, TINY_SCENE, smk_dry_run
from snakemake_runner import job_stats, smk
from tiny_results import tiny_scene

from flatlandia import geo, proposals
from flatlandia.classes import CLASSES
from flatlandia.data import export, reference_map
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError

TEST_CONFIGS = REPO / "config" / "test"
TEXT = {"scene": str, "token": str}
SCENE_FILES = {
    "reference_map": "reference_map.csv",
    "queries": "queries.csv",
    "local_maps": "local_maps.csv",
    "proposals": "proposals.csv",
    "ground_truth": "ground_truth.csv",
}


@pytest.fixture(scope="module")
def tiny_parquet(tmp_path_factory) -> dict:
    """The tiny scene's reference_map.parquet and queries.parquet, written as rules reference_map
    and queries write them, and read back as rule export_scene reads them."""
    tiny = tiny_scene()
    d = tmp_path_factory.mktemp("tiny_parquet")
    reference_map.write_geoparquet(tiny.ref, tiny.meta, d / "reference_map.parquet")
    files.write_parquet(tiny.queries, d / "queries.parquet", {"scene": TINY_SCENE})
    return {
        "ref": pd.read_parquet(d / "reference_map.parquet"),
        "meta": files.read_parquet_metadata(d / "reference_map.parquet"),
        "queries": pd.read_parquet(d / "queries.parquet"),
    }


def _coarse_table(ref: pd.DataFrame, q: pd.DataFrame, loss: str, strategies, scene: str = TINY_SCENE) -> pd.DataFrame:
    """A proposal table shaped like rule coarse_eval's / coarse_solver's (every scene, the test
    split, per map type and strategy, with the metrics the export must not carry)."""
    rng = np.random.default_rng(len(loss))
    rows = []
    for r in q[q["split"] == "test"].itertuples(index=False):
        for mt in ("gt", "depth"):
            for k, strat in enumerate(strategies):
                prop = [int(o) for o in rng.permutation(ref["obj_idx"].to_numpy())[: 3 + k]]
                rows.append(
                    dict(
                        scene=scene, token=r.token, loss=loss, map_type=mt, strategy=strat, proposal=prop, precision=0.5
                    )
                )
    # a row of another scene, and one of a query not in this scene: neither is exported
    rows.append(dict(scene="other", token="x", loss=loss, map_type="gt", strategy="N_LM", proposal=[0], precision=1.0))
    rows.append(dict(scene=scene, token="nope", loss=loss, map_type="gt", strategy="N_LM", proposal=[0], precision=1.0))
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def coarse(tiny_parquet) -> dict:
    ref, q = tiny_parquet["ref"], tiny_parquet["queries"]
    return {
        "coarse-sim": _coarse_table(ref, q, "Sim", ["N_LM", "2N_LM", "R_30"]),
        "coarse-solver": _coarse_table(ref, q, "Solver", ["N_LM", "2N_LM", "R_30", "BB"]),
    }


@pytest.fixture(scope="module")
def written(tiny_parquet, coarse, tmp_path_factory) -> dict:
    """The tiny scene exported with two coarse sources, written as rule export_scene writes it and
    read back with pandas (scene and token as text)."""
    out = export.scene_export(TINY_SCENE, tiny_parquet["ref"], tiny_parquet["meta"], tiny_parquet["queries"], coarse)
    d = tmp_path_factory.mktemp("export")
    for name, fname in SCENE_FILES.items():
        files.write_text(export.csv_text(out[name]), d / fname)
    files.write_json(out["frame"], d / "frame.json")
    files.write_text(json.dumps(out["reference_geojson"]) + "\n", d / "reference_map.geojson")
    files.write_text(json.dumps(out["query_cameras"], indent=1) + "\n", d / "query_cameras.geojson")
    back = {name: pd.read_csv(d / fname, dtype=TEXT, keep_default_na=False) for name, fname in SCENE_FILES.items()}
    return {"out": out, "back": back, "dir": d}


# ---------------------------------------------------------------- read back = the Parquet values
def test_reference_map_reads_back_exactly(tiny_parquet, written):
    ref, back = tiny_parquet["ref"], written["back"]["reference_map"]
    assert list(back.columns) == export.REFERENCE_COLUMNS
    assert back["obj_idx"].tolist() == ref["obj_idx"].tolist()
    assert back["class_id"].tolist() == ref["class_id"].tolist()
    assert back["class"].tolist() == ref["class_label"].tolist() == [CLASSES[c] for c in ref["class_id"]]
    for c in ("lon", "lat", "x_m", "y_m"):
        assert np.array_equal(back[c].to_numpy(float), ref[c].to_numpy(float)), c  # exact, not close
    gj = json.loads((written["dir"] / "reference_map.geojson").read_text())
    assert len(gj["features"]) == len(ref)
    f = gj["features"][3]
    assert f["geometry"]["coordinates"] == [ref["lon"][3], ref["lat"][3]]
    assert list(f["properties"]) == export.REFERENCE_COLUMNS and f["properties"]["x_m"] == ref["x_m"][3]


def test_frame_is_the_reference_maps(tiny_parquet, written):
    frame = json.loads((written["dir"] / "frame.json").read_text())
    meta = tiny_parquet["meta"]
    assert {k: frame[k] for k in ("crs", "lon0", "lat0", "axes", "unit")} == {
        k: meta[k] for k in ("crs", "lon0", "lat0", "axes", "unit")
    }
    assert frame["crs"].startswith("+proj=tmerc") and frame["unit"] == "m"


def test_local_maps_read_back_exactly_and_queries_hold_no_truth(tiny_parquet, written):
    q, back = tiny_parquet["queries"], written["back"]
    assert list(back["queries"].columns) == ["token", "split", "n_objects"]  # no pose, no matches
    assert back["queries"]["token"].tolist() == q["token"].tolist()
    assert back["queries"]["n_objects"].tolist() == q["n_objects"].tolist()
    lm = back["local_maps"]
    assert list(lm.columns) == export.LOCAL_MAP_COLUMNS
    assert len(lm) == 2 * q["n_objects"].sum()
    for r in q.itertuples(index=False):
        for mt, col in (("gt", "gt_local_xy_m"), ("depth", "depth_local_xy")):
            rows = lm[(lm["token"] == r.token) & (lm["map_type"] == mt)]
            assert rows["k"].tolist() == list(range(r.n_objects))
            assert (rows["split"] == r.split).all()
            assert rows["class_id"].tolist() == list(r.classes)
            assert np.array_equal(rows[["x", "y"]].to_numpy(float), np.stack(getattr(r, col)))
    depth = lm[lm["map_type"] == "depth"]
    ranges = np.hypot(depth["x"], depth["y"]).groupby(depth["token"]).median()
    assert np.allclose(ranges, 1.0)  # normalised: the median object range is 1


def test_ground_truth_reads_back_and_places_each_gt_map_on_its_matches(tiny_parquet, written):
    q, back = tiny_parquet["queries"], written["back"]
    gt = back["ground_truth"]
    assert list(gt.columns) == export.GROUND_TRUTH_COLUMNS
    for c in ("x_m", "y_m", "theta_deg", "lon", "lat"):
        assert np.array_equal(gt[c].to_numpy(float), q[c].to_numpy(float)), c
    ref = back["reference_map"].set_index("obj_idx")
    lm = back["local_maps"]
    worst = 0.0
    for r in gt.itertuples(index=False):
        local = lm[(lm["token"] == r.token) & (lm["map_type"] == "gt")].sort_values("k")[["x", "y"]].to_numpy(float)
        matched = [int(i) for i in r.matched_obj_idx.split(" ")]
        placed = geo.local_to_world(local, np.array([r.x_m, r.y_m]), np.radians(r.theta_deg))
        assert np.array_equal(placed, export.place_local_map(local, r.x_m, r.y_m, r.theta_deg))
        worst = max(worst, float(np.linalg.norm(placed - ref.loc[matched, ["x_m", "y_m"]].to_numpy(), axis=1).max()))
        # the matched objects' classes are the local map's
        assert (
            ref.loc[matched, "class_id"].tolist()
            == lm[(lm["token"] == r.token) & (lm["map_type"] == "gt")]["class_id"].tolist()
        )
    assert worst < 1e-6


def test_query_cameras_load_in_a_gis_as_a_point_layer(tiny_parquet, written):
    """query_cameras.geojson: valid GeoJSON that GDAL (pyogrio, what QGIS reads with) opens as a point
    layer in WGS 84, one camera per query with its token (as text), split and compass heading."""
    import geopandas as gpd
    import pyogrio

    path = written["dir"] / "query_cameras.geojson"
    q = tiny_parquet["queries"]
    info = pyogrio.read_info(path)
    assert info["geometry_type"] == "Point" and info["features"] == len(q)
    layer = gpd.read_file(path, engine="pyogrio")
    assert layer.crs.to_epsg() == 4326
    assert layer["token"].tolist() == q["token"].astype(str).tolist()
    assert pd.api.types.is_string_dtype(layer["token"])  # text, as GDAL read it: not a number
    assert layer["split"].tolist() == q["split"].tolist() and set(layer["split"]) == {"train", "val", "test"}
    assert np.array_equal(layer.geometry.x.to_numpy(), q["lon"].to_numpy(float))
    assert np.array_equal(layer.geometry.y.to_numpy(), q["lat"].to_numpy(float))
    assert np.array_equal(layer["heading_deg"].to_numpy(), export.heading_deg(q["theta_deg"]))
    doc = json.loads(path.read_text())  # RFC 7946: a FeatureCollection of Features, [lon, lat] positions
    assert doc["type"] == "FeatureCollection" and "crs" not in doc
    assert all(f["type"] == "Feature" and len(f["geometry"]["coordinates"]) == 2 for f in doc["features"])


def test_heading_is_the_compass_form_of_theta(written):
    gt = written["back"]["ground_truth"]
    theta, heading = np.radians(gt["theta_deg"].to_numpy(float)), np.radians(gt["heading_deg"].to_numpy(float))
    # the viewing axis (east, north): (cos theta, sin theta) counter-clockwise from east = (sin h, cos h) clockwise from north
    assert np.allclose(np.cos(theta), np.sin(heading), atol=1e-12)
    assert np.allclose(np.sin(theta), np.cos(heading), atol=1e-12)
    assert ((gt["heading_deg"] >= 0) & (gt["heading_deg"] < 360)).all()


@pytest.mark.parametrize(
    ("theta", "heading"),
    [(90.0, 0.0), (0.0, 90.0), (180.0, 270.0), (-180.0, 270.0), (-90.0, 180.0), (135.0, 315.0), (450.0, 0.0)],
)
def test_heading_values(theta, heading):
    assert export.heading_deg([theta])[0] == pytest.approx(heading, abs=1e-12)


def test_heading_never_reaches_360():
    h = export.heading_deg([90.0 + 1e-14, 90.0 + 1e-300, 450.0 + 1e-13])
    assert ((h >= 0) & (h < 360)).all()


# ---------------------------------------------------------------- proposals
def test_gtbb_proposals_are_the_workflows_for_both_map_types(tiny_parquet, written):
    pr = written["back"]["proposals"]
    assert list(pr.columns) == export.PROPOSAL_COLUMNS  # no precision / recall: no ground truth
    box = proposals.gtbb_proposals(tiny_parquet["ref"], tiny_parquet["queries"])
    assert len(box) == len(tiny_parquet["queries"])  # every split
    for r in box.itertuples(index=False):
        for mt in ("gt", "depth"):
            rows = pr[(pr["token"] == r.token) & (pr["source"] == "gtbb") & (pr["map_type"] == mt)]
            assert (rows["strategy"] == "GT-BB").all()
            assert rows["obj_idx"].tolist() == list(r.proposal)


def test_coarse_proposals_are_the_tables_rows_of_this_scene(tiny_parquet, coarse, written):
    pr = written["back"]["proposals"]
    tokens = set(tiny_parquet["queries"]["token"])
    test = set(tiny_parquet["queries"].loc[tiny_parquet["queries"]["split"] == "test", "token"])
    for source, table in coarse.items():
        mine = table[(table["scene"] == TINY_SCENE) & table["token"].isin(tokens)]
        for r in mine.itertuples(index=False):
            rows = pr[
                (pr["token"] == r.token)
                & (pr["source"] == source)
                & (pr["map_type"] == r.map_type)
                & (pr["strategy"] == r.strategy)
            ]
            assert rows["obj_idx"].tolist() == r.proposal
        assert set(pr.loc[pr["source"] == source, "token"]) == test
    assert "x" not in set(pr["token"]) and "nope" not in set(pr["token"])
    assert set(pr["source"]) == {"gtbb", "coarse-sim", "coarse-solver"}


def test_proposal_rows_are_ordered(written, tiny_parquet):
    pr = written["back"]["proposals"]
    order = [
        pr["source"].map(export.SOURCES.index),
        pr["map_type"].map(export.MAP_TYPES.index),
        pr["strategy"].map(export.STRATEGIES.index),
        pr["token"].map(list(tiny_parquet["queries"]["token"]).index),
    ]
    keys = list(zip(*order))
    assert keys == sorted(keys)


def test_unknown_or_strange_proposals_are_refused(tiny_parquet, coarse):
    ref, meta, q = tiny_parquet["ref"], tiny_parquet["meta"], tiny_parquet["queries"]
    with pytest.raises(ValueError, match="unknown proposal sources"):
        export.scene_export(TINY_SCENE, ref, meta, q, {"coarse-magic": coarse["coarse-sim"]})
    odd = coarse["coarse-sim"].assign(strategy="R_99")
    with pytest.raises(InputError, match="R_99"):
        export.scene_export(TINY_SCENE, ref, meta, q, {"coarse-sim": odd})


def test_a_map_without_geographic_frame_is_refused(tiny_parquet):
    meta = reference_map.local_frame_metadata(TINY_SCENE, "sfm")
    with pytest.raises(InputError, match="no geographic frame"):
        export.scene_export(TINY_SCENE, tiny_parquet["ref"], meta, tiny_parquet["queries"])


def test_the_export_is_deterministic(tiny_parquet, coarse):
    a = export.scene_export(TINY_SCENE, tiny_parquet["ref"], tiny_parquet["meta"], tiny_parquet["queries"], coarse)
    shuffled = {s: t.sample(frac=1.0, random_state=1) for s, t in coarse.items()}
    b = export.scene_export(TINY_SCENE, tiny_parquet["ref"], tiny_parquet["meta"], tiny_parquet["queries"], shuffled)
    for name in SCENE_FILES:
        assert export.csv_text(a[name]) == export.csv_text(b[name]), name


# ---------------------------------------------------------------- the index files
def test_index_files(tiny_parquet, tmp_path):
    scene = {"scene": TINY_SCENE, "city": "Flat|land <b>*x*</b>", **tiny_parquet}
    out = export.index_export([scene], ["coarse-solver"])
    for name in ("classes", "scenes", "template"):
        files.write_text(export.csv_text(out[name]), tmp_path / f"{name}.csv")
    classes = pd.read_csv(tmp_path / "classes.csv")
    assert classes["class"].tolist() == CLASSES and classes["class_id"].tolist() == list(range(len(CLASSES)))
    scenes = pd.read_csv(tmp_path / "scenes.csv", dtype=TEXT).iloc[0]
    q = tiny_parquet["queries"]
    assert list(out["scenes"].columns) == export.SCENE_COLUMNS
    assert scenes["n_objects"] == len(tiny_parquet["ref"])
    assert [scenes[f"n_queries_{s}"] for s in ("train", "val", "test")] == [
        int((q["split"] == s).sum()) for s in ("train", "val", "test")
    ]
    assert scenes["crs"] == tiny_parquet["meta"]["crs"] and scenes["lon0"] == tiny_parquet["meta"]["lon0"]
    template = pd.read_csv(tmp_path / "template.csv", dtype=TEXT)
    assert list(template.columns) == ["scene", "token", "x_m", "y_m", "theta_deg"]
    assert template["token"].tolist() == q.loc[q["split"] == "test", "token"].tolist()
    assert template[["x_m", "y_m", "theta_deg"]].isna().all().all()
    readme = out["readme"]
    assert readme.endswith(export.FILES_MARKDOWN)
    assert "Flat\\|land &lt;b&gt;\\*x\\*&lt;/b&gt;" in readme and "<b>" not in readme  # escaped
    assert "`gtbb`, `coarse-solver`." in readme
    assert "**Absent**: `coarse-sim`, `coarse-trip`, `coarse-simtrip`" in readme
    full = export.index_export([scene], list(export.COARSE_SOURCES))["readme"]
    assert "**Absent**" not in full


def test_the_usage_page_carries_the_exports_text():
    """docs/usage.md, section "Export the benchmark", holds what results/export/README.md says of its files."""
    usage = (REPO / "docs" / "usage.md").read_text()
    section = usage.split("## Export the benchmark", 1)[1].split("\n## ", 1)[0]
    assert export.FILES_MARKDOWN in section


@pytest.mark.parametrize(
    "values",
    [[0.1, 1 / 3, 1e-20, 123456789.123, -0.0, 2.0, 5e-324, 1.7976931348623157e308, -31.859631838467475]],
)
def test_floats_round_trip_in_positional_notation(tmp_path, values):
    df = pd.DataFrame({"v": values + [np.nan], "i": range(len(values) + 1)})
    text = export.csv_text(df)
    assert "e" not in text.split("\n", 1)[1]  # positional: no exponent
    files.write_text(text, tmp_path / "f.csv")
    back = pd.read_csv(tmp_path / "f.csv")
    assert back["v"].iloc[:-1].tolist() == values and np.isnan(back["v"].iloc[-1])
    assert text.splitlines()[-1] == f",{len(values)}"  # NaN: an empty cell


# ---------------------------------------------------------------- the workflow
def test_dry_run_exports_without_training(repo, tmp_path):
    """On a fresh folder the target builds the maps and queries it needs and nothing of the coarse stage."""
    res = smk_dry_run(repo, tmp_path, "export", "--configfile", str(TEST_CONFIGS / "tiny.yaml"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    planned = job_stats(res.stdout)
    assert planned == {
        "ingest": 1,
        "recover": 1,
        "reference_map": 1,
        "queries": 1,
        "export_scene": 1,
        "export_index": 1,
        "export_original": 1,
        "export": 1,
        "total": 8,
    }


@pytest.mark.slow  # the published data (flat_root)
def test_export_two_scenes(repo, flat_root, tmp_path):
    """`snakemake export` on scenes 9 and 12 in a fresh folder: no model trained, every file there,
    the coarse sources reported absent, the CSVs equal to the Parquet files."""
    configs = [str(TEST_CONFIGS / "two_scenes.yaml")]
    res = smk(
        repo, tmp_path, "--cores", "2", "export", "--configfile", *configs, "--config", f"flatlandia_root={flat_root}"
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert not (tmp_path / "results/coarse").exists()
    ex = tmp_path / "results/export"
    scenes = pd.read_csv(ex / "scenes.csv", dtype=TEXT)
    assert scenes["scene"].tolist() == ["9", "12"] and scenes["city"].tolist() == ["Lisbon", "Paris"]
    readme = (ex / "README.md").read_text()
    assert "**Absent**: `coarse-sim`, `coarse-trip`, `coarse-simtrip`, `coarse-solver`" in readme
    assert (
        "absent sources: coarse-sim, coarse-trip, coarse-simtrip, coarse-solver"
        in (tmp_path / "logs/export_scene/12.log").read_text()
    )
    template = pd.read_csv(ex / "poses_template.csv", dtype=TEXT)
    for s in ("9", "12"):
        ref = pd.read_parquet(tmp_path / f"results/{s}/maps/reference_map.parquet")
        q = pd.read_parquet(tmp_path / f"results/{s}/queries/queries.parquet")
        back = pd.read_csv(ex / f"{s}/reference_map.csv", dtype=TEXT)
        assert np.array_equal(
            back[["x_m", "y_m", "lon", "lat"]].to_numpy(), ref[["x_m", "y_m", "lon", "lat"]].to_numpy()
        )
        gt = pd.read_csv(ex / f"{s}/ground_truth.csv", dtype=TEXT)
        assert np.array_equal(gt[["x_m", "y_m", "theta_deg"]].to_numpy(), q[["x_m", "y_m", "theta_deg"]].to_numpy())
        assert set(pd.read_csv(ex / f"{s}/proposals.csv", dtype=TEXT)["source"]) == {"gtbb"}
        cams = json.loads((ex / f"{s}/query_cameras.geojson").read_text())["features"]
        assert [f["properties"]["token"] for f in cams] == q["token"].astype(str).tolist()
        assert len(pd.read_csv(ex / f"{s}/local_maps.csv", dtype=TEXT)) == 2 * q["n_objects"].sum()
        assert template.loc[template["scene"] == s, "token"].tolist() == q.loc[q["split"] == "test", "token"].tolist()
        assert (
            json.loads((ex / f"{s}/frame.json").read_text())["crs"]
            == files.read_parquet_metadata(tmp_path / f"results/{s}/maps/reference_map.parquet")["crs"]
        )
