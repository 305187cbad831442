"""The stages' entry functions, which the rule scripts and the benchmarks both call: what each
returns for a known input, and that it is the chain the stage's parts make by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import published_scene

from flatlandia import checkpoints, config, geo
from flatlandia.city import simulate
from flatlandia.classes import CLASSES
from flatlandia.coarse import evaluation as coarse_evaluation
from flatlandia.coarse import retrieval
from flatlandia.coarse import training as coarse_training
from flatlandia.data import published, queries, reference_map
from flatlandia.fine import models, training
from flatlandia.images import gps_alignment
from flatlandia.objects import cloud, clustering, labels, principal_plane, scene_objects
from flatlandia.plumbing.errors import InputError

CLUSTER = config.section_defaults("objects.cluster")
SPLIT = {"train": 0.8, "val": 0.1, "test": 0.1}


# --------------------------------------------------------------------------- objects


@pytest.fixture(scope="module")
def scene12_cloud(flat_root):
    pts, point_labels = cloud.read_classified_cloud(flat_root / "maps/12/class_segmented_point_cloud.ply")
    t = published.read_transformations(flat_root / "maps/12/transformations.json")
    return pts, point_labels, t


@pytest.mark.slow  # the published data (flat_root)
def test_published_objects_are_the_clusters_through_the_published_chain(flat_root, scene12_cloud):
    pts, point_labels, t = scene12_cloud
    lonlat = published.read_reference_map(flat_root / "individual_reference_maps/map_12.json")[0]
    others = [
        published.read_reference_map(flat_root / f"individual_reference_maps/map_{s}.json")[1] for s in ("0", "9")
    ]
    out = scene_objects.published_objects("12", pts, point_labels, t, lonlat, others, CLUSTER, source="cloud 12")
    # by hand: clusters, the label prior of the other maps, positions through the chain
    objs, member = clustering.cluster_objects(
        pts, point_labels, cloud.metres_per_unit(t), clustering.ClusterParams.from_dict(CLUSTER), with_members=True
    )
    prior = labels.class_prior(others)
    ref = labels.objects_reference_map(objs, t, geo.frame_for(lonlat), prior)
    assert list(out.objects["scene"].unique()) == ["12"]
    pd.testing.assert_frame_equal(out.objects[ref.columns].reset_index(drop=True), ref)
    assert out.objects[["cx", "cy", "cz", "box_ex"]].equals(objs[["cx", "cy", "cz", "box_ex"]])
    assert out.meta["class_prior"] == prior and out.meta["cluster_params"] == CLUSTER
    assert out.meta["lon0"] == geo.frame_for(lonlat).lon0
    # members: every clustered point once, the object sizes add up
    assert np.array_equal(out.members["point_index"], np.flatnonzero(member >= 0))
    assert len(out.members) == int(out.objects["n_points"].sum())
    assert out.summary.startswith(f"scene 12: {int((point_labels != cloud.BACKGROUND).sum())} classified of")


def _points(cls_a: int, cls_b: int) -> pd.DataFrame:
    """Two tight blobs of SfM points 10 units apart, classes cls_a and cls_b."""
    rng = np.random.default_rng(0)
    xyz = np.vstack([rng.normal(0, 0.02, (20, 3)), rng.normal(0, 0.02, (20, 3)) + [10, 0, 0]])
    return pd.DataFrame(
        {
            "point3D_id": np.arange(40, dtype=np.int64),
            "x": xyz[:, 0],
            "y": xyz[:, 1],
            "z": xyz[:, 2],
            "class_id": [cls_a] * 20 + [cls_b] * 20,
        }
    )


LOCAL = {
    "mode": "none",
    "A": [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
    "b": [1.0, -1.0],
    "crs": None,
    "frame_lon0": None,
    "frame_lat0": None,
    "unit": "SfM unit x 2 (assumed metres)",
    "metres_per_sfm_unit": 2.0,
}


def test_images_objects_in_a_local_frame():
    pole = CLASSES.index(next(c for c in CLASSES if cloud.MACRO_OF_CLASS.get(CLASSES.index(c)) == "pole"))
    out = scene_objects.images_objects("s", _points(pole, pole), LOCAL, pd.DataFrame(), CLUSTER)
    assert len(out.objects) == 2 and set(out.objects["class_id"]) == {pole}
    assert np.allclose(np.sort(out.objects["x_m"].to_numpy()), [1.0, 21.0], atol=0.5)  # 2 x + 1
    assert out.objects[["lon", "lat"]].isna().all().all()  # no GPS, no lon/lat
    assert out.meta["frame"] == "local" and out.meta["unit"] == LOCAL["unit"] and "empty_because" not in out.meta
    assert out.meta["instance_split"] is False
    assert list(out.members.columns) == ["point3D_id", "object_id"] and (out.members["object_id"] >= 0).all()


def test_images_objects_without_object_points_say_why():
    background = labels.NOT_AN_OBJECT
    out = scene_objects.images_objects("s", _points(background, background), LOCAL, pd.DataFrame(), CLUSTER)
    assert out.objects.empty and out.meta["empty_because"] == scene_objects.NO_OBJECT_POINTS
    assert (out.members["object_id"] == -1).all() and len(out.members) == 40


@pytest.mark.slow  # the published data (flat_root)
def test_principal_plane_report_of_scene12(scene12_cloud):
    pts, point_labels, t = scene12_cloud
    out = principal_plane.published_plane_report("12", pts, point_labels, t, source="cloud 12")
    assert out["scene"] == "12" and out["plane_angle_deg"] < 1.0  # measured 0.86 deg (tests/test_align.py)
    assert out["plane_source"].startswith("class point cloud, ground classes")
    assert out["metres_per_sfm_unit"] == cloud.metres_per_unit(t)
    plane, _ = principal_plane.fit_ground_plane(pts, point_labels, cloud.metres_per_unit(t))  # config defaults
    assert out["plane_normal"] == plane.normal.tolist() and out["chain_metric_scale_m_per_unit"] > 0
    rot = np.asarray(out["our_plane_rotation"])
    assert np.allclose(rot[:, 2], out["plane_normal"]) and np.isclose(np.linalg.det(rot), 1.0)


# --------------------------------------------------------------------------- maps and queries


@pytest.mark.slow  # the published data (flat_root)
def test_published_reference_map_and_queries_are_the_workflow_chain(flat_root):
    from flatlandia.data import recover

    lonlat, classes = published.read_reference_map(flat_root / "individual_reference_maps/map_9.json", len(CLASSES))
    frame = geo.frame_for(lonlat)
    ref_by_hand = reference_map.reference_table("9", lonlat, classes, CLASSES, frame)
    local = published.read_local_maps(flat_root / "local_maps.json", "9")
    rec = recover.recover_scene("9", lonlat, classes, local)
    q_by_hand = queries.build_queries(
        "9", rec, ref_by_hand, local, frame, queries.split_queries(list(rec["token"]), 0, salt="9")
    )
    ref, meta = reference_map.published_reference_map("9", lonlat, classes)
    pd.testing.assert_frame_equal(ref, ref_by_hand)
    assert meta["frame"] == "gps" and meta["lon0"] == geo.frame_for(lonlat).lon0
    q, qmeta = queries.published_scene_queries("9", rec, ref, meta, local, 0, SPLIT)
    pd.testing.assert_frame_equal(q, q_by_hand)
    assert qmeta == {**meta, "seed": 0, "split": SPLIT}
    assert queries.split_fractions(SPLIT) == (0.8, 0.1, 0.1)


def test_images_reference_map_keeps_labelled_objects_in_their_frame():
    objs = pd.DataFrame(
        {
            "object_id": [4, 5, 6],
            "class_id": [1, labels.NOT_AN_OBJECT, 2],
            "lon": [np.nan] * 3,
            "lat": [np.nan] * 3,
            "x_m": [1.0, 2.0, 3.0],
            "y_m": [4.0, 5.0, 6.0],
        }
    )
    ref, meta = reference_map.images_reference_map("s", objs, {"frame": "local", "unit": "SfM unit"})
    assert list(ref["object_id"]) == [4, 6] and list(ref["obj_idx"]) == [0, 1]
    assert list(ref["x_m"]) == [1.0, 3.0] and list(ref["class_label"]) == [CLASSES[1], CLASSES[2]]
    assert meta["frame"] == "local" and meta["crs"] is None and meta["source"].startswith("images")
    gps = {"frame": "gps", "lon0": 13.19, "lat0": 55.70}
    ref, meta = reference_map.images_reference_map("s", objs.assign(lon=13.19, lat=55.70), gps)
    assert meta["lon0"] == 13.19 and meta["crs"] == geo.MetricFrame(13.19, 55.70).proj4


def _camera(name: str, centre, registered: bool = True):
    """A pycolmap-like image looking along +x with its y axis down (world z up)."""
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    mat = np.hstack([R, (-R @ np.asarray(centre, float))[:, None]])
    pose = SimpleNamespace(matrix=lambda: mat)
    return SimpleNamespace(name=name, has_pose=registered, camera_id=1, cam_from_world=lambda: pose, points2D=[])


def test_scene_alignment_local_and_gps():
    centres = {f"{k:02d}.jpg": [5.0 * k, 3.0 * (k % 2), 0.0] for k in range(6)}
    images = {k: _camera(n, c) for k, (n, c) in enumerate(centres.items())}
    images[9] = _camera("99.jpg", [0.0, 0.0, 0.0], registered=False)
    cam = SimpleNamespace(calibration_matrix=lambda: np.eye(3), width=100, height=80)
    rec = SimpleNamespace(images=images, cameras={1: cam})
    frame = geo.MetricFrame(13.19, 55.70)
    xy_m = 2.0 * np.array([c[:2] for c in centres.values()]) + [30.0, -10.0]  # 2 m per SfM unit
    lonlat = frame.to_lonlat(xy_m)
    table = pd.DataFrame(
        {"name": list(centres)[::-1] + ["99.jpg"], "lon": [*lonlat[::-1, 0], 13.0], "lat": [*lonlat[::-1, 1], 55.0]}
    ).assign(alt=np.nan, heading=np.nan)
    align = dict(config.section_defaults("images.align"))
    local = gps_alignment.scene_alignment("s", rec, table, {**align, "mode": "none"}, 0)
    assert local["scene"] == "s" and local["cameras"] == sorted(centres)  # registered ones, by name
    by_hand = gps_alignment.local_frame(
        np.array([centres[n] for n in sorted(centres)]), np.array([images[0].cam_from_world().matrix()[:, :3]] * 6)
    )
    assert geo.alignment_is_local(local) and np.allclose(local["A"], by_hand["A"]) and "no GPS" in local["method"]
    out = gps_alignment.scene_alignment("s", rec, table, align, 0, source="cameras")
    assert out["cameras"] == sorted(centres) and out["method"].endswith("RANSAC similarity to GPS")
    assert out["metres_per_sfm_unit"] == pytest.approx(2.0, rel=1e-3)
    assert out["median_residual_m"] < 0.01


# --------------------------------------------------------------------------- fine and coarse training


@pytest.fixture(scope="module")
def scene9_pair(scene9):
    return [scene9]


FINE = dict(model="MLP", map_type="gt", hidden=16, epochs=2, batch_size=32, augment=False)


@pytest.mark.slow  # the published data (flat_root)
def test_training_samples_per_regime(scene9_pair):
    cfg = models.FineTrainConfig(**FINE)
    q = scene9_pair[0][1]
    n_train, n_val = int((q["split"] == "train").sum()), int((q["split"] == "val").sum())
    ct = {"copies": 2, "keep_gtbb": True, "crop_m": 0.0}
    train_s, val_s = training.training_samples(scene9_pair, cfg, "gtbb", ct)
    assert len(train_s) <= n_train and len(val_s) <= n_val and len(train_s) > 0.9 * n_train
    coarse_train, coarse_val = training.training_samples(scene9_pair, cfg, "coarse", ct)
    assert len(coarse_train) == 3 * len(train_s) and len(coarse_val) == 2 * len(val_s)  # GT-BB + copies
    again = training.training_samples(scene9_pair, cfg, "coarse", ct)[0]
    assert all(np.array_equal(a.local.numpy(), b.local.numpy()) for a, b in zip(coarse_train, again))  # seeded
    _, val_only = training.training_samples(scene9_pair, cfg, "coarse", ct, val_keep_gtbb=False)
    assert len(val_only) == len(val_s)


@pytest.mark.slow  # the published data (flat_root)
def test_fine_train_model_is_training_on_those_samples(scene9_pair, tmp_path):
    cfg = models.FineTrainConfig(**FINE)
    ct = {"copies": 1, "keep_gtbb": True, "crop_m": 0.0}
    res, history, meta = training.train_model(scene9_pair, cfg, "gtbb", ct)
    by_hand = training.train(*training.training_samples(scene9_pair, cfg, "gtbb", ct), cfg)
    assert history.equals(pd.DataFrame(by_hand["history"])) and len(history) == 2
    assert meta["train_proposals"] == "gtbb" and meta["coarse_training"] is None and meta["warm_start"] is None
    assert meta["n_parameters"] == checkpoints.n_parameters(res["model"]) and meta["config"] == cfg.to_dict()
    path = tmp_path / "start.pt"
    checkpoints.save_checkpoint(res, path)
    _, _, warm = training.train_model(scene9_pair, cfg, "coarse", ct, init=str(path))
    assert warm["warm_start"] == str(path) and warm["coarse_training"] == ct
    ref, q = scene9_pair[0]
    with pytest.raises(InputError, match="0 validation samples"):
        training.train_model([(ref, q[q["split"] != "val"])], cfg, "gtbb", ct, source="queries.parquet")


@pytest.mark.slow  # the published data (flat_root)
def test_coarse_training_dataset_and_model(scene9_pair):
    from flatlandia.coarse import target

    ref, q = scene9_pair[0]
    scenes = [(ref, q, target.scene_similarity(ref, q))]
    cfg = retrieval.CoarseTrainConfig(loss="simtrip", epochs=1, seed=0)
    ds = coarse_training.training_dataset(scenes, cfg)
    assert ds.split("train") and ds.split("val")
    res, history, meta = coarse_training.train_model(ds, cfg)
    assert len(history) == 1 and meta["best_epoch"] == res["best_epoch"] and meta["config"] == cfg.to_dict()
    with pytest.raises(InputError, match="0 validation queries"):
        coarse_training.training_dataset([(ref, q[q["split"] != "val"], scenes[0][2])], cfg, source="q.parquet")
    # rule coarse_eval on that model: per-loss proposals of the test split, Table 3 and its note
    model = res["model"]
    out = coarse_evaluation.evaluate_models({"Sim+Trip": (model, cfg)}, scenes, pd.DataFrame(), seed=0)
    assert set(out.proposals) == {"Sim+Trip"} and set(out.proposals["Sim+Trip"]["loss"]) == {"Sim+Trip"}
    assert set(out.proposals["Sim+Trip"]["scene"].astype(str)) == {"9"}
    assert "Sim+Trip: 1 epochs" in out.note and "Scoring one query" in out.note
    assert {"Sim+Trip", "-", "random", "S oracle"} <= set(out.table["loss"])
    other = retrieval.CoarseTrainConfig(loss="sim", epochs=1, seed=0, knn=cfg.knn + 1)
    with pytest.raises(ValueError, match="different graph settings"):
        coarse_evaluation.evaluate_models({"Sim+Trip": (model, cfg), "Sim": (model, other)}, scenes, pd.DataFrame())


# --------------------------------------------------------------------------- city


@pytest.mark.slow  # the published data (flat_root)
def test_scene_cities_skip_scenes_without_queries_and_are_seeded(flat_root, scene9):
    ref12, q12 = published_scene(flat_root, "12")
    refs = {"9": scene9[0], "12": ref12}
    qs = {"9": scene9[1], "12": q12.assign(split="train")}  # scene 12: no val query
    cities = list(simulate.scene_cities(["9", "12"], refs, qs, 2000, 1000.0, 2.0, 0, "val"))
    assert [s for s, _, _ in cities] == ["9"]
    _, ref, q = cities[0]
    assert len(ref) >= 2000 and set(q.loc[q["scene"] == "9", "token"]) == set(scene9[1]["token"])
    rng = np.random.default_rng([0, 0])  # scene 9 is first: seeded with (seed, 0)
    by_hand = simulate.city([refs["9"]], [qs["9"]], [simulate.Template(ref12, qs["12"])], 2000, 1000.0, 2.0, rng)
    pd.testing.assert_frame_equal(ref, by_hand[0])


# --------------------------------------------------------------------------- sfm


@pytest.mark.slow
def test_sfm_reconstruct_cleans_a_camera_far_from_its_gps(lund, tmp_path):
    from flatlandia.images import image_audit, sfm

    images = config.section_defaults("images")
    table = image_audit.audit_table(lund, images["dedup_threshold"], images["missing_gps"])
    table = table[table["name"].isin([f"{k:02d}.jpg" for k in range(1, 9)])].reset_index(drop=True)
    moved = "04.jpg"  # its GPS fix 500 m north: the cleaning must drop it, whatever SfM made of it
    table.loc[table["name"] == moved, "lat"] += 500 / 111_320
    options = {**config.section_defaults("sfm"), "max_image_size": 800}
    messages = []
    rec, stats, cameras = sfm.reconstruct(lund, table, None, tmp_path / "w", options, 0, log=messages.append)
    s = stats.iloc[0]
    assert s["registered"] == rec.num_reg_images() == len(cameras) and s["images_input"] == 8
    assert moved not in set(cameras["name"]) and f"{moved}: over 50.0 m from its GPS fix" in s["removed"]
    assert s["removed_cameras"] >= 1 and s["gps_prior_images"] == len(cameras)
    assert s["model_frame"].startswith("metric") and any(m.startswith("removed ") for m in messages)
    assert list(cameras.columns) == ["image_id", "name", "x", "y", "z", "lat", "lon", "alt", "heading"]
