"""Images scenes: ground plane from upright cameras, robust GPS alignment, objects on the aligned map."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.images import gps_alignment
from flatlandia.objects import clustering, labels
from flatlandia.plumbing.errors import InputError

FRAME = geo.MetricFrame(lon0=13.195, lat0=55.698)


def _upright(yaw: float) -> np.ndarray:
    """cam_from_world rotation of a level camera looking along yaw (world z up)."""
    f = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    d = np.array([0.0, 0.0, -1.0])
    r = np.cross(d, f)  # right = down x forward keeps right x down = forward
    return np.vstack([r, d, f])


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.fixture
def walk():
    """A walk along a straight street (collinear cameras), seen in an arbitrary SfM frame."""
    rng = np.random.default_rng(3)
    n = 30
    s = np.linspace(0, 150, n)
    heading = np.radians(70.0)
    world = np.column_stack([s * np.cos(heading), s * np.sin(heading), 1.6 + 0.05 * rng.standard_normal(n)])
    yaws = heading + np.radians(rng.uniform(-40, 40, n))
    R_world = np.array([_upright(y) @ _rot([1, 0, 0], np.radians(rng.normal(0, 3))) for y in yaws])
    Q = _rot([0.3, -0.5, 0.8], 1.1)  # world -> SfM rotation
    s0, t0 = 0.037, np.array([4.0, -2.0, 7.0])
    centres = (s0 * world @ Q.T) + t0
    R_sfm = R_world @ Q.T
    gps_xy = world[:, :2] + rng.normal(0, 5.0, (n, 2))
    gps_xy[[4, 17]] += [[80.0, -60.0], [-70.0, 90.0]]  # two wild fixes
    compass = 90.0 - np.degrees(yaws)  # clockwise from north
    return dict(
        world=world,
        centres=centres,
        R=R_sfm,
        lonlat=FRAME.to_lonlat(gps_xy),
        s0=s0,
        Q=Q,
        t0=t0,
        compass=compass,
        alt=world[:, 2] + 30.0,
    )


def test_up_axis_and_right_handed_basis(walk):
    up = gps_alignment.camera_up(walk["R"])
    true_up = walk["Q"] @ np.array([0, 0, 1.0])
    assert np.degrees(np.arccos(np.clip(up @ true_up, -1, 1))) < 2.0
    P = gps_alignment.plane_basis(up)
    assert np.allclose(P @ P.T, np.eye(2)) and np.allclose(np.cross(P[0], P[1]), up)


def test_alignment_of_a_straight_walk_with_noisy_gps_and_outliers(walk):
    out = gps_alignment.fit_gps_alignment(
        walk["centres"],
        walk["R"],
        walk["lonlat"],
        altitude=walk["alt"],
        compass_deg=walk["compass"],
        threshold_m=15.0,
        seed=0,
    )
    # the two wild fixes are outliers, the rest inliers
    assert out["inliers"] >= 26 and not out["inlier_mask"][4] and not out["inlier_mask"][17]
    assert out["metres_per_sfm_unit"] == pytest.approx(1 / walk["s0"], rel=0.05)
    # mapped camera centres land on the true positions (GPS noise 5 m averages out)
    mapped = geo.alignment_points(out, walk["centres"])
    true_xy = geo.alignment_frame(out).to_xy(FRAME.to_lonlat(walk["world"][:, :2]))
    err = np.linalg.norm(mapped - true_xy, axis=1)
    assert np.median(err) < 3.0
    assert 2.0 < out["inlier_median_residual_m"] < 9.0  # the GPS noise itself
    assert out["compass_median_diff_deg"] < 5.0 and out["compass_within_30deg"] == 1.0
    assert out["altitude_median_residual_m"] < 0.5


def test_alignment_needs_three_cameras_with_gps(walk):
    lonlat = walk["lonlat"].copy()
    lonlat[2:] = np.nan
    with pytest.raises(InputError, match="only 2 registered camera"):
        gps_alignment.fit_gps_alignment(walk["centres"], walk["R"], lonlat, source="cams.parquet")


def _points(clusters, rng):
    rows = []
    for cx, cy, cls, n in clusters:
        xyz = np.array([cx, cy, 0.0]) + rng.normal(0, 0.15, (n, 3))
        rows += [(x, y, z, cls) for x, y, z in xyz]
    bg = rng.uniform(-20, 20, (200, 3))
    rows += [(x, y, z, 255) for x, y, z in bg]
    df = pd.DataFrame(rows, columns=["x", "y", "z", "class_id"])
    df.insert(0, "point3D_id", np.arange(len(df)))
    return df


def test_scene_objects_cluster_label_and_place(walk):
    rng = np.random.default_rng(0)
    pole, sign = CLASSES.index("object--support--pole"), CLASSES.index("object--traffic-sign")
    pts = _points([(5, 5, pole, 30), (12, -3, pole, 25), (-8, 4, sign, 20)], rng)
    alignment = {
        "A": [[1.0, 0, 0], [0, 1.0, 0]],
        "b": [0.0, 0.0],
        "metres_per_sfm_unit": 1.0,
        "frame_lon0": FRAME.lon0,
        "frame_lat0": FRAME.lat0,
    }
    objs, member = labels.images_scene_objects("t", pts, alignment, clustering.ClusterParams(eps_m=1.0), CLASSES)
    assert len(objs) == 3
    got = sorted(zip(np.round(objs["x_m"]).astype(int), np.round(objs["y_m"]).astype(int), objs["class_id"]))
    assert got == sorted([(5, 5, pole), (12, -3, pole), (-8, 4, sign)])
    assert (member[pts["class_id"].to_numpy() == 255] == -1).all()
    assert (member >= 0).sum() == 75
    ll = FRAME.to_lonlat(objs[["x_m", "y_m"]].to_numpy())
    assert np.allclose(ll, objs[["lon", "lat"]].to_numpy())


def test_scene_without_object_points_is_an_empty_result():
    rng = np.random.default_rng(1)
    pts = _points([], rng)
    alignment = {
        "A": [[1.0, 0, 0], [0, 1.0, 0]],
        "b": [0.0, 0.0],
        "metres_per_sfm_unit": 1.0,
        "frame_lon0": FRAME.lon0,
        "frame_lat0": FRAME.lat0,
    }
    objs, member = labels.images_scene_objects("t", pts, alignment, clustering.ClusterParams(), CLASSES)
    assert objs.empty and (member == -1).all() and {"x_m", "class_id", "box_cx"} <= set(objs.columns)


def test_cameras_far_from_their_gps_are_flagged(walk):
    far = gps_alignment.gps_outliers(walk["centres"], walk["R"], walk["lonlat"], max_residual_m=50.0)
    assert set(np.flatnonzero(far)) == {4, 17}  # the two wild fixes, 100+ m off; GPS noise of 5 m is not
    few = walk["lonlat"].copy()
    few[2:] = np.nan
    assert not gps_alignment.gps_outliers(walk["centres"], walk["R"], few, max_residual_m=50.0).any()
