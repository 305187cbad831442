"""Queries of an images scene: 3DoF poses, detections and local maps from SfM + objects + alignment.

The alignment is an affine map of SfM points onto the scene's metric ground plane,
``xy = A @ X + b`` with ``A`` (2x3) = scale x planar rotation x projection on the principal
plane. Directions map with ``A`` alone, so a camera's heading is the angle of ``A @ d`` for its
viewing direction ``d``.

Detections are the objects' 3D boxes projected into each image where at least
``min_points`` of the object's points are observed, clipped to the image. Queries are images
detecting at least ``min_objects`` objects. Local maps (camera at the origin looking along +x,
+y left, metres):
- GT: the detected objects' map positions in the camera frame;
- depth (``sparse`` backend): each detection's centre pixel lifted to the median camera depth
  of the SfM points observed inside the detection, then projected on the ground plane.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import config, geo
from flatlandia.data.localmaps import normalise_depth_map, oracle_scale
from flatlandia.data.queries import QUERY_COLUMNS
from flatlandia.images.views import View, pose_3dof, project, sparse_depth_point, views_from_colmap

#: Defaults: the `images` section of workflow/schemas/config.schema.yaml.
_IMAGES = config.section_defaults("images")


def detections(view: View, objects: pd.DataFrame, point_object: dict[int, int], min_points: int) -> pd.DataFrame:
    """Objects seen by a view: clipped projected 3D box, number of observed points.

    ``objects`` needs ``object_id`` and ``corners`` (8x3 box corners in SfM coordinates);
    ``point_object`` maps SfM point id -> object id.
    """
    seen: dict[int, int] = {}
    for pid in view.obs_point_ids:
        oid = point_object.get(int(pid))
        if oid is not None:
            seen[oid] = seen.get(oid, 0) + 1
    rows = []
    by_id = objects.set_index("object_id")
    for oid, n in sorted(seen.items()):
        if n < min_points:
            continue
        corners = np.asarray(by_id.loc[oid, "corners"], float).reshape(8, 3)
        uv, z = project(view, corners)
        if (z <= 0).all():
            continue
        uv = uv[z > 0]
        x0, y0 = np.clip(uv.min(0), 0, [view.width, view.height])
        x1, y1 = np.clip(uv.max(0), 0, [view.width, view.height])
        if x1 - x0 < 1 or y1 - y0 < 1:
            continue
        rows.append({"object_id": int(oid), "n_points": n, "box": [float(x0), float(y0), float(x1), float(y1)]})
    return pd.DataFrame(rows, columns=["object_id", "n_points", "box"])


def scene_queries(
    scene: str,
    views: list[View],
    objects: pd.DataFrame,
    point_object: dict[int, int],
    point_xyz: dict[int, np.ndarray],
    A: np.ndarray,
    b: np.ndarray,
    obj_xy: dict[int, np.ndarray],
    obj_class: dict[int, int],
    min_objects: int = _IMAGES["min_objects"],
    min_points: int = _IMAGES["min_points"],
    lift=None,
) -> pd.DataFrame:
    """The queries table of an images scene, in the published scenes' schema (docs/usage.md, "queries.parquet").

    ``lift(view, box)`` gives a detection's world point for the depth local map (default: the
    sparse SfM depth; see :mod:`flatlandia.images.depth` for the monocular backend).
    """
    if lift is None:

        def lift(view, box):
            return sparse_depth_point(view, box, point_xyz)

    rows = []
    for v in views:
        det = detections(v, objects, point_object, min_points)
        if len(det) < min_objects:
            continue
        cam_xy, theta = pose_3dof(v, A, b)
        ids = det["object_id"].tolist()
        gt = geo.world_to_local(np.array([obj_xy[i] for i in ids]), cam_xy, theta)
        depth = []
        for box in det["box"]:
            X = lift(v, box)
            depth.append([np.nan, np.nan] if X is None else geo.world_to_local((A @ X + b)[None], cam_xy, theta)[0])
        depth = np.asarray(depth, float)
        rows.append(
            {
                "scene": scene,
                "token": v.name,
                "n_objects": len(ids),
                "ref_idx": ids,
                "classes": [int(obj_class[i]) for i in ids],
                "x_m": float(cam_xy[0]),
                "y_m": float(cam_xy[1]),
                "theta_deg": float(np.degrees(theta)),
                "gt_local_xy_m": gt.tolist(),
                "depth_local_xy_m": depth.tolist(),
                "boxes": det["box"].tolist(),
            }
        )
    cols = [
        "scene",
        "token",
        "n_objects",
        "ref_idx",
        "classes",
        "x_m",
        "y_m",
        "theta_deg",
        "gt_local_xy_m",
        "depth_local_xy_m",
        "boxes",
    ]
    return pd.DataFrame(rows, columns=cols)


#: an images scene's queries.parquet has every column of a published scene's
#: (:data:`flatlandia.data.queries.QUERY_COLUMNS`), then its own: metric depth map and detection boxes
IMAGES_ONLY_QUERY_COLUMNS = ["depth_local_xy_m", "boxes"]


def query_table(q: pd.DataFrame, frame: geo.MetricFrame | None, split: dict[str, str]) -> pd.DataFrame:
    """An images scene's queries in the published scenes' schema: lon/lat (NaN in a local frame,
    ``frame`` None), the depth map normalised to a median object range of 1, the split, the oracle
    depth scale; the recovery diagnostics say the pose comes from SfM (resolution ``sfm``, one
    solution, no residual)."""
    q = q.copy()
    xy = q[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2)
    ll = frame.to_lonlat(xy) if frame is not None and len(q) else np.full((len(q), 2), np.nan)
    q["lon"], q["lat"] = ll[:, 0], ll[:, 1]
    depth = [normalise_depth_map(np.asarray(d, float).reshape(-1, 2))[0] for d in q["depth_local_xy_m"]]
    q["depth_local_xy"] = [d.tolist() for d in depth]
    q["split"] = q["token"].map(split).astype(str) if len(q) else pd.Series(dtype=str)
    q["depth_oracle_scale_m"] = [oracle_scale(d, np.asarray(g, float)) for d, g in zip(depth, q["gt_local_xy_m"])]
    q["residual_m"] = np.nan
    q["ambiguous"] = False
    q["resolution"] = "sfm"
    q["n_solutions"] = 1
    q["second_residual_m"] = np.nan
    q["second_cam_dist_m"] = np.nan
    return q[QUERY_COLUMNS + IMAGES_ONLY_QUERY_COLUMNS].reset_index(drop=True)


def images_scene_queries(
    scene: str,
    rec,
    alignment: dict,
    ref: pd.DataFrame,
    objects: pd.DataFrame,
    members: pd.DataFrame,
    images: dict,
    seed: int,
    split: dict,
    device="cpu",
) -> tuple[pd.DataFrame, dict]:
    """Rule queries on an images scene -> (query table, its Parquet metadata).

    ``rec``: the GPS-aligned SfM model (a ``pycolmap.Reconstruction``); ``alignment``: rule
    gps_alignment's record; ``ref``, ``objects``, ``members``: the scene's reference map, objects
    and point -> object table; ``images``: the config's images section (min_objects, min_points,
    depth, images_dir); ``device``: where the transformers depth backend runs (config ``device``).
    Queries are the registered images that see at least ``min_objects`` of the
    reference map's objects (:func:`scene_queries`), indexed by the map's row (``obj_idx``) as the
    published scenes are, split as the published scenes are (config ``seed``, ``split``).
    """
    from flatlandia.data import queries
    from flatlandia.images import depth
    from flatlandia.objects import clustering

    views = views_from_colmap(rec)
    objs = objects[objects["object_id"].isin(ref["object_id"])].reset_index(drop=True)
    members = members[members["object_id"].isin(objs["object_id"])]
    point_object = dict(zip(members["point3D_id"].astype(int), members["object_id"].astype(int)))
    point_xyz = {int(pid): np.asarray(p.xyz, float) for pid, p in rec.points3D.items()}
    objs["corners"] = [clustering.box_corners(r).tolist() for r in objs.itertuples(index=False)]
    # queries index the reference map by its row (obj_idx), as the published scenes do
    idx_of = dict(zip(ref["object_id"].astype(int), ref["obj_idx"].astype(int)))
    objs["object_id"] = objs["object_id"].map(idx_of)
    point_object = {k: idx_of[v] for k, v in point_object.items()}
    obj_xy = {int(r.obj_idx): np.array([r.x_m, r.y_m]) for r in ref.itertuples(index=False)}
    obj_class = dict(zip(ref["obj_idx"].astype(int), ref["class_id"].astype(int)))
    A, b = np.asarray(alignment["A"], float), np.asarray(alignment["b"], float)
    dcfg = dict(images["depth"])
    lift = depth.make_lifter(
        dcfg["backend"],
        point_xyz,
        images_dir=images["images_dir"],
        weights=dcfg["weights"],
        inverse=bool(dcfg["inverse"]),
        device=device,
    )
    q = scene_queries(
        scene,
        views,
        objs,
        point_object,
        point_xyz,
        A,
        b,
        obj_xy,
        obj_class,
        min_objects=int(images["min_objects"]),
        min_points=int(images["min_points"]),
        lift=lift,
    )
    frame = geo.alignment_frame(alignment)  # None: a local frame (no GPS), no lon/lat
    labels = queries.split_queries(q["token"].tolist(), int(seed), queries.split_fractions(split), salt=scene)
    q = query_table(q, frame, labels)
    meta = {
        "scene": scene,
        "source": "images",
        "frame": "local" if frame is None else "gps",
        "crs": None if frame is None else frame.proj4,
        "unit": alignment.get("unit", "m"),
        "views": len(views),
        "min_objects": int(images["min_objects"]),
        "depth_backend": dcfg["backend"],
    }
    return q, meta
