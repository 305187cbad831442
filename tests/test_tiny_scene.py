"""The fast lane's own scene: tests/data/tiny, one synthetic street in the published format (made by
tests/data/make_tiny_scene.py, seed fixed). Readers, ingest, query recovery, queries and split, the
solver on GT and depth maps, proposals, the committed test configs and a Snakemake dry run, with
no published data; one real run of `maps` on it (slow: it runs Snakemake jobs)."""

from __future__ import annotations

import importlib.util
import json
import shutil

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO, TINY_ROOT, TINY_SCENE, smk_dry_run
from snakemake_runner import job_stats, smk
from tiny_results import tiny_scene

from flatlandia import config, geo, proposals, solver
from flatlandia.classes import CLASSES
from flatlandia.coarse import solver_proposals
from flatlandia.data import ingest, localmaps, published, queries, recover, scene_inputs
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError

TEST_CONFIGS = REPO / "config" / "test"


def _maker():
    spec = importlib.util.spec_from_file_location("make_tiny_scene", TINY_ROOT.parent / "make_tiny_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


maker = _maker()


@pytest.fixture(scope="module")
def truth() -> dict:
    """What the generator made, the truth the files do not hold (SfM points, camera poses, matches)."""
    return maker.build()


@pytest.fixture(scope="module")
def tiny() -> dict:
    """The tiny scene built as the workflow builds a published scene (rules reference_map, recover,
    queries; split seed 0)."""
    s = tiny_scene()
    split = dict(zip(s.queries["token"], s.queries["split"]))
    return dict(
        lonlat=s.lonlat,
        classes=s.classes,
        frame=s.frame,
        ref=s.ref,
        local=s.local_maps,
        rec=s.recovered,
        split=split,
        queries=s.queries,
    )


def _same_numbers(a, b) -> bool:
    """Same JSON structure, numbers equal to 1e-12 (a platform's last bit of a sine may differ)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_numbers(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same_numbers(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return bool(np.isclose(a, b, rtol=1e-12, atol=1e-15))
    return a == b


# ---------------------------------------------------------------- the data folder
def test_committed_scene_is_what_the_script_makes(tmp_path):
    """tests/data/tiny is the generator's output: edit the script and run it, never the files."""
    maker.write(tmp_path)
    made = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(TINY_ROOT).as_posix() for p in TINY_ROOT.rglob("*") if p.is_file())
    assert made == committed
    for rel in made:
        new, old = (tmp_path / rel).read_text(), (TINY_ROOT / rel).read_text()
        if rel.endswith(".json"):
            assert _same_numbers(json.loads(new), json.loads(old)), rel
        elif rel != "MANIFEST.tsv":  # sizes and hashes follow the JSON digits
            assert new == old, rel


def test_readers_take_the_published_format(tiny, truth):
    lonlat, classes, local = tiny["lonlat"], tiny["classes"], tiny["local"]
    assert lonlat.shape == (maker.N_OBJECTS, 2) and classes.shape == (maker.N_OBJECTS,)
    assert len(set(classes)) >= 5 and classes.max() < len(CLASSES)
    assert published.read_classes(TINY_ROOT / "classes.tsv") == list(CLASSES)
    sheet = published.read_tsv(TINY_ROOT / "scenes.tsv", ["scene", "city", "name"])
    assert sheet.astype(str).values.tolist() == [[TINY_SCENE, maker.CITY, maker.NAME]]
    assert len(local) == maker.N_QUERIES
    for maps in local.values():
        assert maps["GT"].shape == maps["depth"].shape and len(maps["GT"]) >= 3
        assert (maps["GT"][:, 0] > 0).all()  # the camera looks along +x
        ratio = np.linalg.norm(maps["depth"], axis=1) / np.linalg.norm(maps["GT"], axis=1)
        assert 0.001 < np.median(ratio) < 0.01  # the published depth maps' arbitrary scale
    tokens = (TINY_ROOT / f"maps/{TINY_SCENE}/tokens.txt").read_text().split()
    assert set(local) < set(tokens) and len(tokens) == maker.N_QUERIES + len(truth["extra_tokens"])
    t = published.read_transformations(TINY_ROOT / f"maps/{TINY_SCENE}/transformations.json")
    assert np.linalg.det(np.asarray(t["to_principal_plane"])) == pytest.approx(-1.0)  # a reflection, as most are
    with pytest.raises(InputError, match=r"unknown scene id '9'; scenes present: \['0'\]"):
        published.read_local_maps(TINY_ROOT / "local_maps.json", "9")
    with pytest.raises(InputError, match="fewer than 9"):
        published.read_local_maps(TINY_ROOT / "local_maps.json", TINY_SCENE, min_objects=9)


def test_the_published_chain_puts_the_sfm_points_on_the_map(truth):
    """geo.sfm_to_lonlat (row form, X @ Rpp) against DATA.md's column form the generator used: with
    a reflection for Rpp, the transpose matters."""
    t = published.read_transformations(TINY_ROOT / f"maps/{TINY_SCENE}/transformations.json")
    lonlat, _ = published.read_reference_map(TINY_ROOT / f"individual_reference_maps/map_{TINY_SCENE}.json")
    np.testing.assert_allclose(geo.sfm_to_lonlat(truth["sfm"], t), lonlat, rtol=0, atol=1e-12)
    wrong = dict(t, to_principal_plane=np.asarray(t["to_principal_plane"]).T.tolist())  # Rpp for Rpp^T
    assert np.abs(geo.sfm_to_lonlat(truth["sfm"], wrong) - lonlat).max() > 1e-4  # tens of metres off


def test_ingest_checks_every_file_against_the_manifest(tiny_root, tmp_path):
    rep = ingest.ingest_scene(tiny_root, TINY_SCENE)
    assert rep["n_queries"] == maker.N_QUERIES
    avail = rep["available"]
    assert avail["reference_map"] and avail["transformations"] and avail["tokens"] and avail["local_maps"]
    assert not (avail["sfm_cameras"] or avail["class_segmented_point_cloud"] or avail["bbs"])
    present = [r for r in rep["files"] if r["present"]]
    assert present and all(r["manifest"] and r["size_ok"] and r["sha256_ok"] and r["parse_ok"] for r in present)
    # one digit changed, size kept: the hash catches it; a truncated file: its size
    data = tmp_path / "data"
    shutil.copytree(tiny_root, data)
    ref = data / f"individual_reference_maps/map_{TINY_SCENE}.json"
    text = ref.read_text()
    k = text.index(".") + 3
    ref.write_text(text[:k] + ("1" if text[k] != "1" else "2") + text[k + 1 :])
    with pytest.raises(InputError, match="sha256 differs from MANIFEST.tsv"):
        ingest.ingest_scene(data, TINY_SCENE)
    assert ingest.ingest_scene(data, TINY_SCENE, verify_hash=False)["n_queries"] == maker.N_QUERIES
    ref.write_text(text[: len(text) // 2])
    with pytest.raises(InputError, match="truncated"):
        ingest.ingest_scene(data, TINY_SCENE, verify_hash=False)


# ---------------------------------------------------------------- recovery, queries, split
def test_recovery_finds_every_camera_and_the_objects_it_sees(tiny, truth):
    rec = tiny["rec"].set_index("token")
    assert rec["recovered"].all() and len(rec) == maker.N_QUERIES
    assert (rec["residual_m"] < 1e-6).all() and (rec["resolution"] == "unique").all()
    for q in truth["queries"]:
        r = rec.loc[q["token"]]
        assert list(r["ref_idx"]) == q["objects"]  # in the local map's order
        np.testing.assert_allclose([r["lon"], r["lat"]], q["lonlat"], rtol=0, atol=1e-11)
        assert np.degrees(geo.wrap_angle(np.radians(r["theta_lonlat_deg"]) - q["theta"])) == pytest.approx(0, abs=1e-7)


def test_a_local_map_that_fits_nowhere_is_not_recovered_and_stops_the_queries(tiny):
    token = sorted(tiny["local"])[0]
    local = {t: dict(m) for t, m in tiny["local"].items()}
    moved = local[token]["GT"].copy()
    moved[0] += 0.5 / (geo.UNIT_DEG * 111_000)  # half a metre off: beyond recover.tol_m (0.1 m)
    local[token]["GT"] = moved
    rec = recover.recover_scene(TINY_SCENE, tiny["lonlat"], tiny["classes"], local)
    assert rec.set_index("token")["recovered"].to_dict() == {t: t != token for t in sorted(local)}
    with pytest.raises(InputError, match="1 queries could not be recovered"):
        queries.build_queries(TINY_SCENE, rec, tiny["ref"], local, tiny["frame"], tiny["split"])


def test_the_shared_recipe_is_the_chain_of_the_stage_functions(tiny, tmp_path):
    """flatlandia.data.scene_inputs (the recipe every test of the tiny scene, conftest.published_scene
    and users share) gives what the stage functions give by hand, and writes the rules' files."""
    from flatlandia.data import reference_map

    lonlat, classes = published.read_reference_map(
        TINY_ROOT / f"individual_reference_maps/map_{TINY_SCENE}.json", len(CLASSES)
    )
    frame = geo.frame_for(lonlat)
    ref = reference_map.reference_table(TINY_SCENE, lonlat, classes, CLASSES, frame)
    local = published.read_local_maps(TINY_ROOT / "local_maps.json", TINY_SCENE)
    rec = recover.recover_scene(TINY_SCENE, lonlat, classes, local, tol_m=config.section_defaults("recover")["tol_m"])
    split = queries.split_queries(list(rec["token"]), config.section_defaults()["seed"], salt=TINY_SCENE)
    q = queries.build_queries(TINY_SCENE, rec, ref, local, frame, split)
    pd.testing.assert_frame_equal(tiny["ref"], ref)
    pd.testing.assert_frame_equal(tiny["rec"], rec)
    pd.testing.assert_frame_equal(tiny["queries"], q)
    assert tiny["split"] == split and len(tiny_scene().split("test")) == list(split.values()).count("test")
    results = tmp_path / "results"
    path = tiny_scene().write(results, geojson=True)
    assert path == results / TINY_SCENE / "maps" / "reference_map.parquet" and path.with_suffix(".geojson").exists()
    pd.testing.assert_frame_equal(pd.read_parquet(path).drop(columns="geometry"), ref)  # GeoParquet adds the points
    pd.testing.assert_frame_equal(pd.read_parquet(results / TINY_SCENE / "queries" / "queries.parquet"), q)
    assert files.read_parquet_metadata(path)["lon0"] == frame.lon0
    other = scene_inputs.published_scene(TINY_ROOT, TINY_SCENE, {"seed": 7})  # the config's settings are used
    assert dict(zip(other.queries["token"], other.queries["split"])) == queries.split_queries(
        list(rec["token"]), 7, salt=TINY_SCENE
    )


def test_split_is_seeded_per_scene_and_independent_of_order(tiny):
    tokens = sorted(tiny["local"])
    split = queries.split_queries(tokens, 0, salt=TINY_SCENE)
    assert pd.Series(split).value_counts().to_dict() == {"train": 10, "val": 1, "test": 1}
    assert queries.split_queries(tokens[::-1], 0, salt=TINY_SCENE) == split
    assert queries.split_queries(tokens, 1, salt=TINY_SCENE) != split
    assert queries.split_queries(tokens, 0, salt="1") != split
    assert tiny["split"] == split
    with pytest.raises(ValueError, match="must sum to 1"):
        queries.split_queries(tokens, 0, (0.8, 0.1, 0.2))


def test_query_table_holds_metric_gt_maps_and_normalised_depth_maps(tiny):
    q, ref = tiny["queries"], tiny["ref"]
    assert list(q.columns) == queries.QUERY_COLUMNS and len(q) == maker.N_QUERIES
    xy = ref[["x_m", "y_m"]].to_numpy()
    rec, mpd = tiny["rec"].set_index("token"), tiny["frame"].metres_per_degree()
    turns = []
    for r in q.itertuples(index=False):
        gt = localmaps.local_map(r, "gt")
        world = xy[list(r.ref_idx)]
        # rigid copies in metres: distances kept, the camera put back gives the objects
        dl = np.linalg.norm(gt[:, None] - gt[None], axis=-1)
        np.testing.assert_allclose(dl, np.linalg.norm(world[:, None] - world[None], axis=-1), atol=1e-6)
        np.testing.assert_allclose(geo.local_to_world(gt, [r.x_m, r.y_m], np.radians(r.theta_deg)), world, atol=1e-6)
        assert (gt[:, 0] > 0).all() and list(r.classes) == ref["class_id"].to_numpy()[list(r.ref_idx)].tolist()
        # the published (degree-unit) GT map carried into metres is the metric GT map (< 1 cm)
        carried = localmaps.published_to_metric_frame(
            tiny["local"][r.token]["GT"], np.radians(rec.loc[r.token, "theta_lonlat_deg"]), np.radians(r.theta_deg), mpd
        )
        np.testing.assert_allclose(carried, gt, atol=0.01)
        depth = localmaps.local_map(r, "depth")
        assert np.median(np.linalg.norm(depth, axis=1)) == pytest.approx(1.0)
        # metric bearings, off by the generator's noise only (1.5 degrees sigma in lon/lat degrees, up
        # to 1.5 times that in metres: east-west is stretched)
        turn = np.degrees(geo.wrap_angle(np.arctan2(depth[:, 1], depth[:, 0]) - np.arctan2(gt[:, 1], gt[:, 0])))
        assert np.abs(turn).max() < 10.0
        turns.extend(np.abs(turn))
        assert 3.0 < r.depth_oracle_scale_m < 60.0  # metres per normalised unit: the median range
    assert np.median(turns) < 2.0


# ---------------------------------------------------------------- the solver and proposals
def test_solver_is_exact_on_gt_maps(tiny):
    q, ref = tiny["queries"], tiny["ref"]
    xy, cls = ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy()
    for r in q.itertuples(index=False):
        s = solver.solve(localmaps.local_map(r, "gt"), np.asarray(r.classes), xy, cls, metric=True)
        e_m, e_deg = geo.pose_errors(s.x, s.y, s.theta, r.x_m, r.y_m, np.radians(r.theta_deg))
        assert e_m < 1e-3 and e_deg < 1e-3, r.token
        assert sorted(s.inliers) == list(enumerate(r.ref_idx)) and s.scale == 1.0


def test_solver_places_most_depth_maps_within_metres(tiny):
    """Depth maps have an unknown scale and per-object noise: most queries within 2 m, the scale
    near the oracle's; a 3-object query may go wrong."""
    q, ref = tiny["queries"], tiny["ref"]
    xy, cls = ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy()
    errors, scales = [], []
    for r in q.itertuples(index=False):
        s = solver.solve(localmaps.local_map(r, "depth"), np.asarray(r.classes), xy, cls, metric=False)
        errors.append(float(np.hypot(s.x - r.x_m, s.y - r.y_m)))
        scales.append(s.scale / r.depth_oracle_scale_m)
    errors = np.array(errors)
    assert np.median(errors) < 1.5 and (errors < 2.0).sum() >= 6, errors.round(2)
    assert 0.8 < np.median(scales) < 1.25


def test_proposals_hold_the_matched_objects(tiny):
    q, ref = tiny["queries"], tiny["ref"]
    gtbb = proposals.for_queries(ref, q, "gtbb")
    whole = proposals.for_queries(ref, q, "whole")
    assert len(gtbb) == len(whole) == len(q) and (gtbb["strategy"] == "GT-BB").all()
    for r, box, everything in zip(q.itertuples(index=False), gtbb["proposal"], whole["proposal"]):
        assert everything == list(range(maker.N_OBJECTS))
        box_m = proposals.proposal_metrics(box, r.ref_idx)
        assert box_m["recall"] == 1.0 and box_m["success"]
        assert box_m["precision"] >= proposals.proposal_metrics(everything, r.ref_idx)["precision"]
    rng = np.random.default_rng(0)
    sim = proposals.simulated_coarse_proposals(ref, q, rng)
    for r, prop in zip(q.itertuples(index=False), sim["proposal"]):
        assert set(prop) & set(r.ref_idx)  # at least one true object
        assert set(ref["class_id"].to_numpy()[prop]) <= set(r.classes)  # wrong objects of the query's classes
        assert len(prop) <= max(2 * len(r.ref_idx), 1)
    cropped = proposals.crop_to_densest(ref, sim, 10.0)
    assert all(set(c) <= set(p) and c for c, p in zip(cropped["proposal"], sim["proposal"]))


def test_solver_proposals_on_gt_maps_are_the_matched_objects(tiny):
    q, ref = tiny["queries"], tiny["ref"]
    cfg = solver_proposals.SolverProposalConfig()
    rows = solver_proposals.scene_proposals(ref, q, "gt", solver_proposals.scene_candidates(ref), cfg)
    n_lm = rows[rows["strategy"] == "N_LM"]
    assert len(n_lm) == len(q) and (n_lm["precision"] == 1.0).all() and (n_lm["recall"] == 1.0).all()
    assert (rows["pose_error_m"] < 1e-3).all()
    r30 = rows[rows["strategy"] == "R_30"]
    assert r30["success"].all() and (r30["n_proposed"] >= n_lm["n_proposed"].to_numpy()).all()


# ---------------------------------------------------------------- configs and the workflow
@pytest.mark.parametrize("path", sorted(TEST_CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_committed_test_configs_pass_the_schema(path):
    """Every file of config/test holds known keys of the right types (what the workflow checks
    before any job); none names a data folder outside the repository."""
    mine = yaml.safe_load(path.read_text())
    assert isinstance(mine, dict) and mine
    config.resolve(mine)
    root = mine.get("flatlandia_root")
    assert root is None or (REPO / root).resolve().is_relative_to(REPO)


def test_dry_run_plans_the_maps_of_the_tiny_scene(repo, tmp_path):
    res = smk_dry_run(repo, tmp_path, "maps", "--configfile", str(TEST_CONFIGS / "tiny.yaml"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    planned = job_stats(res.stdout)
    assert planned == {
        "ingest": 1,
        "recover": 1,
        "reference_map": 1,
        "queries": 1,
        "plot_reference_map": 1,
        "maps": 1,
        "total": 6,
    }  # no class cloud: no objects; `maps`: no training, no table
    assert str(TINY_ROOT / "local_maps.json") in res.stdout
    assert not (tmp_path / "results").exists()


@pytest.mark.slow  # Snakemake jobs
def test_maps_of_the_tiny_scene_build_without_the_published_data(repo, tmp_path):
    """The per-scene rules for real on the tiny scene (seconds; slow only because it runs jobs)."""
    res = smk(repo, tmp_path, "--cores", "2", "maps", "--configfile", str(TEST_CONFIGS / "tiny.yaml"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    q = pd.read_parquet(tmp_path / f"results/{TINY_SCENE}/queries/queries.parquet")
    assert len(q) == maker.N_QUERIES and (q["residual_m"] < 1e-6).all()
    assert q["split"].value_counts().to_dict() == {"train": 10, "val": 1, "test": 1}
    ref = pd.read_parquet(tmp_path / f"results/{TINY_SCENE}/maps/reference_map.parquet")
    assert len(ref) == maker.N_OBJECTS
    assert (tmp_path / f"results/{TINY_SCENE}/maps/reference_map.png").read_bytes()[:4] == b"\x89PNG"
    assert "12 queries (test 1, train 10, val 1)" in (tmp_path / "results/summary.md").read_text()
