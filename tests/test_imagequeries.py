"""Queries of an images scene on a synthetic street with known cameras and objects."""

import numpy as np
import pandas as pd
import pytest

from flatlandia import geo
from flatlandia.data import queries
from flatlandia.images import image_queries
from flatlandia.images.views import View, project

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _look(centre, yaw):
    """cam_from_world for a camera at `centre` looking horizontally at heading `yaw` (z up)."""
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    left = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    R = np.stack([-left, [0, 0, -1.0], fwd])  # rows: camera x (right), y (down), z (forward)
    return R, -R @ centre


@pytest.fixture
def street():
    rng = np.random.default_rng(0)
    centres = {1: [10, 2, 1], 2: [12, -3, 0.5], 3: [15, 1, 2], 4: [-20, 0, 1]}  # 4 is behind the cameras
    pts, pid, point_object, rows = {}, 0, {}, []
    for oid, c in centres.items():
        c = np.array(c, float)
        for _ in range(20):
            pts[pid] = c + rng.uniform(-0.2, 0.2, 3)
            point_object[pid] = oid
            pid += 1
        corners = np.array(
            [[c[0] + dx, c[1] + dy, c[2] + dz] for dx in (-0.2, 0.2) for dy in (-0.2, 0.2) for dz in (-0.2, 0.2)]
        )
        rows.append({"object_id": oid, "corners": corners.tolist()})
    objects = pd.DataFrame(rows)
    views = []
    for name, (cx, cy, yaw) in {"a.jpg": (0, 0, 0.0), "b.jpg": (2, 1, 0.1)}.items():
        R, t = _look(np.array([cx, cy, 1.5]), yaw)
        v = View(name, K, R, t, 640, 480, np.array([], int), np.zeros((0, 2)))
        ids = np.array(list(pts))
        uv, z = project(v, np.array([pts[i] for i in ids]))
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480)
        v.obs_point_ids, v.obs_xy = ids[ok], uv[ok]
        views.append(v)
    A, b = np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.zeros(2)
    obj_xy = {oid: np.array(c[:2], float) for oid, c in centres.items()}
    return views, objects, point_object, pts, A, b, obj_xy


def test_pose_detections_and_local_maps(street):
    views, objects, point_object, pts, A, b, obj_xy = street
    q = image_queries.scene_queries("s", views, objects, point_object, pts, A, b, obj_xy, {1: 24, 2: 25, 3: 19, 4: 22})
    assert list(q["token"]) == ["a.jpg", "b.jpg"]
    a = q.iloc[0]
    assert a["ref_idx"] == [1, 2, 3] and a["classes"] == [24, 25, 19]  # object 4 is behind: not detected
    assert (a["x_m"], a["y_m"], a["theta_deg"]) == pytest.approx((0, 0, 0), abs=1e-9)
    gt = np.array(a["gt_local_xy_m"])
    assert np.allclose(gt, [[10, 2], [12, -3], [15, 1]])  # +x forward, +y left
    bq = q.iloc[1]
    assert bq["theta_deg"] == pytest.approx(np.degrees(0.1))
    for row in q.itertuples():
        depth, gt = np.array(row.depth_local_xy_m), np.array(row.gt_local_xy_m)
        assert np.abs(depth - gt).max() < 0.5  # sparse depth of a 40 cm object, 10-15 m away
        for x0, y0, x1, y1 in row.boxes:
            assert 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480


def test_too_few_objects_make_no_query(street):
    views, objects, point_object, pts, A, b, obj_xy = street
    q = image_queries.scene_queries(
        "s", views, objects, point_object, pts, A, b, obj_xy, {1: 1, 2: 2, 3: 3, 4: 4}, min_objects=4
    )
    assert q.empty and "gt_local_xy_m" in q.columns


def test_images_scene_queries_have_the_published_schema():
    frame = geo.MetricFrame(13.19, 55.70)
    gt = [[10.0, 1.0], [20.0, -3.0], [15.0, 4.0]]
    q = pd.DataFrame(
        {
            "scene": ["mine"] * 2,
            "token": ["a.jpg", "b.jpg"],
            "n_objects": [3, 3],
            "ref_idx": [[0, 1, 2]] * 2,
            "classes": [[1, 2, 3]] * 2,
            "x_m": [0.0, 100.0],
            "y_m": [0.0, 0.0],
            "theta_deg": [0.0, 90.0],
            "gt_local_xy_m": [gt] * 2,
            "depth_local_xy_m": [[[2 * x, 2 * y] for x, y in gt]] * 2,
            "boxes": [[[0, 0, 1, 1]] * 3] * 2,
        }
    )
    table = image_queries.query_table(q, frame, {"a.jpg": "train", "b.jpg": "test"})
    assert list(table.columns) == queries.QUERY_COLUMNS + image_queries.IMAGES_ONLY_QUERY_COLUMNS
    assert table["split"].tolist() == ["train", "test"] and (table["resolution"] == "sfm").all()
    assert np.allclose(table[["lon", "lat"]].to_numpy()[0], [13.19, 55.70])
    assert table.loc[1, "lon"] > 13.19  # 100 m east
    assert np.median(np.linalg.norm(np.asarray(table.loc[0, "depth_local_xy"]), axis=1)) == pytest.approx(1.0)
    assert table.loc[0, "depth_oracle_scale_m"] == pytest.approx(np.median(np.linalg.norm(gt, axis=1)))
    empty = image_queries.query_table(q.iloc[:0], frame, {})
    assert list(empty.columns) == list(table.columns) and empty.empty
