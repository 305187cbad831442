"""The benchmark in the authors' form (flatlandia.data.original, rule export_original): the exported
camera xy and theta reproduce every published GT local map from the objects' xy, every query is in
one split once, the region proposals index object_list and are the workflow's, the files read back
through the reader (which refuses a broken file naming it and the key) and, as the authors' loader
reads them, give each query its matches and classes. The local-map relation and the loader are
written here from their schema, not taken from their code. On the tiny scene (fast lane), on the
20 published scenes, and as a Snakemake job on two of them (slow)."""

from __future__ import annotations

import copy
import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, TINY_ROOT, TINY_SCENE
from snakemake_runner import smk
from tiny_results import tiny_scene

from flatlandia import geo, proposals, vocabulary
from flatlandia.data import original, scene_inputs
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError

SPLITS = {"train": "training", "val": "validation", "test": "testing"}
TF = 0.0033780547666424354  # their to_flatlandia: one unit is TF / 2 degrees


def _scene_dict(s: scene_inputs.SceneInputs, folder) -> dict:
    """A scene as rule export_original reads it: its tables written as the rules write them and
    read back (Parquet and its metadata)."""
    path = s.write(folder)
    files.write_parquet(s.recovered, folder / s.scene / "queries" / "recovered.parquet")
    q = folder / s.scene / "queries" / "queries.parquet"
    return {
        "scene": s.scene,
        "ref": pd.read_parquet(path),
        "meta": files.read_parquet_metadata(path),
        "recovered": pd.read_parquet(folder / s.scene / "queries" / "recovered.parquet"),
        "queries": pd.read_parquet(q),
        "queries_meta": files.read_parquet_metadata(q),
    }


def _coarse_table(ref: pd.DataFrame, q: pd.DataFrame, loss: str, scene: str = TINY_SCENE) -> pd.DataFrame:
    """A proposal table shaped like rule coarse_eval's (every scene, the test split, per map type and
    strategy, with metrics), plus a row of another scene and one of an unknown query."""
    rng = np.random.default_rng(len(loss))
    rows = []
    for r in q[q["split"] == "test"].itertuples(index=False):
        for mt in vocabulary.MAP_TYPES:
            for k, strat in enumerate(vocabulary.COARSE_STRATEGIES):
                prop = [int(o) for o in rng.permutation(ref["obj_idx"].to_numpy())[: 3 + k]]
                rows.append(dict(scene=scene, token=r.token, loss=loss, map_type=mt, strategy=strat, proposal=prop))
    rows.append(dict(scene="other", token="x", loss=loss, map_type="gt", strategy="N_LM", proposal=[0]))
    rows.append(dict(scene=scene, token="nope", loss=loss, map_type="gt", strategy="N_LM", proposal=[0]))
    return pd.DataFrame(rows).assign(precision=0.5)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict:
    """The tiny scene exported with two coarse sources (and the solver's, which has no key there),
    written by :func:`original.write` and read back with plain ``json`` as the authors' code reads it."""
    d = tmp_path_factory.mktemp("original")
    scene = _scene_dict(tiny_scene(), d / "results")
    coarse = {
        "coarse-sim": _coarse_table(scene["ref"], scene["queries"], "Sim"),
        "coarse-simtrip": _coarse_table(scene["ref"], scene["queries"], "Sim+Trip"),
    }
    published = json.loads((TINY_ROOT / "local_maps.json").read_text())
    out = original.original_export([scene], coarse, published)
    original.write(d / "export", out)
    back = {n: json.loads((d / "export" / rel).read_text()) for n, rel in original.FILES.items() if n != "readme"}
    return {"scene": scene, "coarse": coarse, "out": out, "back": back, "dir": d / "export", "published": published}


# ---------------------------------------------------------------- the checks the issue asks for
def _worst_local_map_error(data: dict, published: dict) -> tuple[float, int]:
    """The largest difference (units) between each published GT local map and the camera's view of
    its detected objects, from the exported xy and theta: p_local = R(-theta) (p_object - p_camera),
    the camera looking along +x, +y to its left. Returns (worst, queries compared)."""
    worst, n = 0.0, 0
    for sid, m in data["maps"].items():
        for token, q in m["queries"].items():
            t = math.radians(q["theta"])
            rot = np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])  # R(-theta)
            obj = np.array([m["objects"][k]["xy"] for k in q["detected_objects"]])
            view = (obj - np.array(q["xy"])) @ rot.T
            worst = max(worst, float(np.abs(view - np.array(published[sid][token]["GT"])).max()))
            n += 1
    return worst, n


def _split_tokens(data: dict) -> list[str]:
    split = data["miscellanea"]["split"]
    return [t for sub in ("simple", "hard") for k in SPLITS.values() for t in split[sub][k]]


def test_exported_poses_reproduce_every_published_gt_local_map(tiny):
    worst, n = _worst_local_map_error(tiny["back"]["flatlandia"], tiny["published"])
    assert n == len(tiny["scene"]["queries"])
    assert worst < 1e-9


def test_every_query_is_in_one_split_once(tiny):
    data, q = tiny["back"]["flatlandia"], tiny["scene"]["queries"]
    tokens = _split_tokens(data)
    assert sorted(tokens) == sorted(q["token"]) and len(set(tokens)) == len(tokens)
    assert set(data["miscellanea"]["split"]["img_to_scene"]) == set(tokens)
    assert set(data["miscellanea"]["split"]["img_to_scene"].values()) == {TINY_SCENE}
    split = data["miscellanea"]["split"]
    for r in q.itertuples(index=False):  # the workflow's split, simple = more than 4 objects
        sub = "simple" if r.n_objects > 4 else "hard"
        assert r.token in split[sub][SPLITS[r.split]]
    assert split["hard"]["testing"] and split["simple"]["training"]  # the tiny scene has both subsets
    notes = data["miscellanea"]["flatlandia_workflow"]
    assert notes["split"]["original"] is False and "not the original" in notes["split"]["note"]


def test_objects_and_cameras_lie_in_the_unit_square_with_their_classes(tiny):
    data, ref = tiny["back"]["flatlandia"], tiny["scene"]["ref"]
    m = data["maps"][TINY_SCENE]
    assert m["object_list"] == [str(o) for o in ref["obj_idx"]]
    xy = np.array([m["objects"][k]["xy"] for k in m["object_list"]] + [q["xy"] for q in m["queries"].values()])
    assert np.isfinite(xy).all() and np.abs(xy).max() < 1
    assert [m["objects"][k]["class"] for k in m["object_list"]] == ref["class_id"].tolist()
    # the centre is the objects' bounding-box centre: the box spans (-a, a) in both axes
    obj = xy[: len(ref)]
    assert np.allclose(obj.min(0), -obj.max(0), atol=1e-12)
    centre = data["miscellanea"]["flatlandia_workflow"]["maps"][TINY_SCENE]["centre_lonlat"]
    assert np.allclose(np.array(centre) + obj * TF / 2, ref[["lon", "lat"]].to_numpy(), rtol=0, atol=1e-12)


def test_their_theta_is_the_lonlat_angle_not_the_metric_one(tiny):
    m, rec = tiny["back"]["flatlandia"]["maps"][TINY_SCENE], tiny["scene"]["recovered"]
    theta = [m["queries"][t]["theta"] for t in rec["token"]]
    assert theta == rec["theta_lonlat_deg"].tolist()
    q = tiny["scene"]["queries"]
    assert not np.allclose(theta, q.set_index("token").loc[rec["token"], "theta_deg"])  # 48 N: they differ


def test_poses_of_their_frame_turn_back_into_the_scene_frame(tiny):
    """original.scene_pose (what the authors' code's predictions go through to be scored) gives back
    the workflow's ground truth from the exported camera xy and theta."""
    data, q = tiny["back"]["flatlandia"], tiny["scene"]["queries"]
    m = data["maps"][TINY_SCENE]
    notes = data["miscellanea"]["flatlandia_workflow"]["maps"][TINY_SCENE]
    frame = geo.MetricFrame(notes["lon0"], notes["lat0"])
    xy = np.array([m["queries"][t]["xy"] for t in q["token"]])
    theta = np.array([m["queries"][t]["theta"] for t in q["token"]])
    x, y, th = original.scene_pose(xy, theta, notes["centre_lonlat"], frame)
    assert np.abs(x - q["x_m"]).max() < 1e-6 and np.abs(y - q["y_m"]).max() < 1e-6
    assert np.abs(geo.wrap_angle(np.radians(th - q["theta_deg"]))).max() < 1e-9


def test_matches_detections_and_null_fields_load_as_their_loader_reads_them(tiny):
    """A query read the way the authors' loader reads one (object keys through object_list, a
    detection per detected key, intrinsics) gives the workflow's matches and classes."""
    data, q = tiny["back"]["flatlandia"], tiny["scene"]["queries"].set_index("token")
    to_scene = data["miscellanea"]["split"]["img_to_scene"]
    for token in _split_tokens(data):
        m = data["maps"][str(to_scene[token])]
        query = m["queries"][token]
        matches = [m["object_list"].index(k) for k in query["detected_objects"]]
        classes = [[m["objects"][k]["class"] for k in m["object_list"]][i] for i in matches]
        detections = [query["detections"][k] for k in query["detected_objects"]]
        assert matches == list(q.loc[token, "ref_idx"]) and classes == list(q.loc[token, "classes"])
        assert detections == [None] * len(matches) and query["intrinsics"] is None
        assert len(tiny["back"]["local_maps"][TINY_SCENE][token]["GT"]) == len(matches)


def test_local_maps_are_the_published_ones(tiny):
    assert tiny["back"]["local_maps"] == {TINY_SCENE: tiny["published"][TINY_SCENE]}


# ---------------------------------------------------------------- proposals
def test_coarsebb_is_the_workflows_gtbb_box_for_both_map_types_and_subsets(tiny):
    rp, ref, q = tiny["back"]["region_proposal"], tiny["scene"]["ref"], tiny["scene"]["queries"]
    box = proposals.gtbb_proposals(ref, q).set_index("token")["proposal"]
    simple = set(q.loc[q["n_objects"] > 4, "token"])
    for mode in ("GT", "depth"):
        assert set(rp[mode]) == {"all", "easy"}
        assert rp[mode]["all"]["CoarseBB"] == {t: [list(box[t])] for t in q["token"]}  # obj_idx = index
        assert rp[mode]["easy"]["CoarseBB"] == {t: v for t, v in rp[mode]["all"]["CoarseBB"].items() if t in simple}


def test_coarse_proposals_are_under_the_keys_of_their_loss_and_size(tiny):
    rp, coarse, q = tiny["back"]["region_proposal"], tiny["coarse"], tiny["scene"]["queries"]
    test = set(q.loc[q["split"] == "test", "token"])
    assert list(rp["GT"]["all"]) == ["CoarseBB"] + [
        f"{p}_{s}" for p in ("simil", "mix") for s in ("nq", "2nq", "circle")
    ]
    suffix = {"N_LM": "nq", "2N_LM": "2nq", "R_30": "circle"}
    for source, prefix in (("coarse-sim", "simil"), ("coarse-simtrip", "mix")):
        t = coarse[source]
        t = t[(t["scene"] == TINY_SCENE) & t["token"].isin(test)]
        for r in t.itertuples(index=False):
            mode = {"gt": "GT", "depth": "depth"}[r.map_type]
            assert rp[mode]["all"][f"{prefix}_{suffix[r.strategy]}"][r.token] == [list(r.proposal)]
        for mode in ("GT", "depth"):
            assert set(rp[mode]["all"][f"{prefix}_2nq"]) == test  # the test split: what the coarse stage makes


def test_every_proposal_indexes_object_list(tiny):
    data, rp = tiny["back"]["flatlandia"], tiny["back"]["region_proposal"]
    to_scene = data["miscellanea"]["split"]["img_to_scene"]
    n = 0
    for mode in rp.values():
        for by_key in mode.values():
            for regions in by_key.values():
                for token, region in regions.items():
                    size = len(data["maps"][to_scene[token]]["object_list"])
                    assert all(isinstance(i, int) and 0 <= i < size for i in region[0])
                    n += 1
    assert n > 0


def test_proposal_keys_cover_the_coarse_losses_and_strategies():
    assert set(original.LOSS_KEYS) == set(vocabulary.COARSE_LOSSES)
    assert set(original.STRATEGY_KEYS) == set(vocabulary.COARSE_STRATEGIES)
    assert original.SOURCES == ["coarse-sim", "coarse-trip", "coarse-simtrip"]
    assert original.proposal_key("coarse-simtrip", "2N_LM") == "mix_2nq"
    assert original.proposal_key("coarse-trip", "R_30") == "triplet_circle"
    assert original.proposal_key("coarse-sim", "N_LM") == "simil_nq"


def test_a_source_or_strategy_without_a_key_is_refused(tiny):
    scene, published = tiny["scene"], tiny["published"]
    with pytest.raises(ValueError, match="without a key"):
        original.region_proposal_json([scene], {"coarse-solver": tiny["coarse"]["coarse-sim"]})
    odd = tiny["coarse"]["coarse-sim"].assign(strategy="BB")
    with pytest.raises(InputError, match="BB"):
        original.original_export([scene], {"coarse-sim": odd}, published)
    # the solver's table is left out of the authors' form (the export_original rule never passes it)
    out = original.original_export([scene], {"coarse-solver": tiny["coarse"]["coarse-sim"]}, published)
    assert list(out["region_proposal"]["GT"]["all"]) == ["CoarseBB"]


# ---------------------------------------------------------------- the reader: check on write
def test_the_files_read_back_through_the_reader(tiny):
    back = original.read(tiny["dir"], tol=original.LOCAL_MAP_TOL)
    assert back == tiny["back"]
    readme = (tiny["dir"] / "README.md").read_text()
    for words in ("regenerated", "not published", "bounding-box centre", "not the original one", "NoisyGT", "null"):
        assert words in readme, words
    assert "**Absent**: `coarse-trip`" in readme


TOKEN_TEST = "565150098230304"  # the tiny scene's test query (3 objects: hard)
TOKEN_TRAIN = "325865384687839"


@pytest.mark.parametrize(
    ("edit", "file", "key"),
    [
        (
            lambda f: f["flatlandia"]["miscellanea"]["split"]["simple"]["validation"].append(TOKEN_TRAIN),
            "flatlandia",
            "listed twice",
        ),
        (
            lambda f: f["flatlandia"]["miscellanea"]["split"]["simple"]["training"].remove(TOKEN_TRAIN),
            "flatlandia",
            "no split lists",
        ),
        (
            lambda f: f["flatlandia"]["maps"]["0"]["objects"]["3"].update(xy=[1.5, 0.0]),
            "flatlandia",
            r"objects\['3'\].xy",
        ),
        (
            lambda f: f["flatlandia"]["maps"]["0"]["objects"]["3"].update({"class": 42}),
            "flatlandia",
            r"objects\['3'\].class",
        ),
        (
            lambda f: f["flatlandia"]["maps"]["0"]["queries"][TOKEN_TEST].update(theta=float("nan")),
            "flatlandia",
            "theta",
        ),
        (
            lambda f: f["flatlandia"]["maps"]["0"]["queries"][TOKEN_TEST].update(detections={}),
            "flatlandia",
            "detections",
        ),
        (
            lambda f: f["flatlandia"]["maps"]["0"]["queries"][TOKEN_TEST]["detected_objects"].append("99"),
            "flatlandia",
            "detected_objects",
        ),
        (
            lambda f: f["region_proposal"]["GT"]["all"]["CoarseBB"][TOKEN_TEST][0].append(30),
            "region_proposal",
            r"CoarseBB\['565150098230304'\]\[0\]",
        ),
        (
            lambda f: f["region_proposal"]["depth"]["easy"]["simil_nq"].update({TOKEN_TEST: [[0, 1]]}),
            "region_proposal",
            "not a query of subset easy",
        ),
        (
            lambda f: f["region_proposal"]["GT"]["all"]["CoarseBB"].pop(TOKEN_TRAIN),
            "region_proposal",
            "not every query",
        ),
        (lambda f: f["local_maps"]["0"][TOKEN_TEST]["depth"].pop(), "local_maps", "'depth'"),
        (
            lambda f: f["local_maps"]["0"][TOKEN_TEST]["GT"][0].__setitem__(
                0, f["local_maps"]["0"][TOKEN_TEST]["GT"][0][0] + 1e-6
            ),
            "local_maps",
            "units from the pose's view",
        ),
    ],
)
def test_the_reader_refuses_a_broken_file_naming_it_and_the_key(tiny, tmp_path, edit, file, key):
    broken = copy.deepcopy(tiny["back"])
    edit(broken)
    paths = {}
    for name, value in broken.items():
        paths[name] = tmp_path / f"{name}.json"
        paths[name].write_text(json.dumps(value))
    with pytest.raises(InputError, match=key) as err:
        original.read(paths, tol=original.LOCAL_MAP_TOL)
    assert str(err.value).startswith(str(paths[file]))


def test_a_file_that_fails_its_check_is_never_written(tiny, tmp_path):
    """write() checks the staged files (the GT maps against the poses too) before moving them in:
    a wrong theta leaves nothing at the target."""
    out = copy.deepcopy(tiny["out"])
    out["flatlandia"]["maps"][TINY_SCENE]["queries"][TOKEN_TEST]["theta"] += 1e-3
    with pytest.raises(InputError, match=r"local_maps.json: \['0'\]\['565150098230304'\]\['GT'\]"):
        original.write(tmp_path / "export", out)
    assert not (tmp_path / "export").exists()


def test_a_query_missing_from_the_published_local_maps_is_refused(tiny):
    published = {TINY_SCENE: {k: v for k, v in tiny["published"][TINY_SCENE].items() if k != TOKEN_TEST}}
    with pytest.raises(InputError, match=f"no local maps of query {TOKEN_TEST}"):
        original.original_export([tiny["scene"]], {}, published, "local_maps.json")


def test_the_rule_writes_the_modules_files():
    """Rule export_original's outputs are original.FILES under results/export/original/ (the script
    stages them together there) and the target lists them."""
    rules = (REPO / "workflow/rules/export.smk").read_text()
    inputs = (REPO / "workflow/rules/inputs/export.smk").read_text()
    listed = re.search(r"EXPORT_ORIGINAL_FILES = (\[.*?\])", inputs).group(1)
    assert json.loads(listed) == list(original.FILES.values())
    for name, rel in original.FILES.items():
        assert f'{name}=paths.export_original("{rel}"),' in rules


# ---------------------------------------------------------------- the published data
@pytest.mark.slow  # the published data (flat_root)
def test_the_20_published_scenes(flat_root, all_local_maps, tmp_path):
    """Every published scene through the recipe of rules reference_map -> recover -> queries,
    exported and read back: every published GT local map reproduced to 1e-9 units from the exported
    poses, every one of the 2,135 queries in one split once, every map and camera in (-1, 1)."""
    scenes = [_scene_dict(scene_inputs.published_scene(flat_root, str(s)), tmp_path / "results") for s in range(20)]
    out = original.original_export(scenes, {}, all_local_maps)
    original.write(tmp_path / "original", out)
    back = original.read(tmp_path / "original", tol=original.LOCAL_MAP_TOL)
    worst, n = _worst_local_map_error(back["flatlandia"], all_local_maps)
    assert n == sum(len(m) for m in all_local_maps.values()) == 2135
    assert worst < 1e-9
    tokens = _split_tokens(back["flatlandia"])
    assert len(tokens) == len(set(tokens)) == 2135
    split = back["flatlandia"]["miscellanea"]["split"]
    assert sum(len(split["simple"][k]) for k in SPLITS.values()) == 1142  # more than 4 objects (docs: DATA.md)
    xy = [o["xy"] for m in back["flatlandia"]["maps"].values() for o in m["objects"].values()]
    xy += [q["xy"] for m in back["flatlandia"]["maps"].values() for q in m["queries"].values()]
    assert np.abs(np.array(xy)).max() < 1
    assert back["local_maps"] == all_local_maps


@pytest.mark.slow  # runs Snakemake jobs on the published data
def test_snakemake_export_original_two_scenes(repo, flat_root, tmp_path):
    """Rule export_original as a job on scenes 9 and 12 in a fresh folder: no model trained, the
    files there and readable, the coarse sources reported absent."""
    target = "results/export/original/README.md"
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        target,
        "--configfile",
        str(REPO / "config/test/two_scenes.yaml"),
        "--config",
        f"flatlandia_root={flat_root}",
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert not (tmp_path / "results/coarse").exists()
    back = original.read(tmp_path / "results/export/original", tol=original.LOCAL_MAP_TOL)
    assert list(back["flatlandia"]["maps"]) == ["9", "12"]
    log = (tmp_path / "logs/export_original/all.log").read_text()
    assert "absent sources: coarse-sim, coarse-trip, coarse-simtrip" in log
    q = pd.read_parquet(tmp_path / "results/12/queries/queries.parquet")
    assert sorted(back["flatlandia"]["maps"]["12"]["queries"]) == sorted(q["token"])
