"""Objects on the map: their 42-class label and their reference-map position.

Published scenes (:func:`objects_reference_map`): the class cloud knows only macro-classes, so
each gets the 42-class most frequent among the *other* scenes' maps (:func:`class_prior`), and
positions go through the published chain. Images scenes (:func:`images_scene_objects`): the
majority 42-class of the object's points, positions through the GPS alignment.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES, N_CLASSES
from flatlandia.objects import clustering
from flatlandia.objects.cloud import BACKGROUND, MACRO_CLASSES, macro_of_class


def class_prior(other_scene_classes: list[np.ndarray]) -> dict[str, int]:
    """Label transfer: per macro-class, the most frequent of its 42 classes in *other* scenes' maps.

    Only class labels of other scenes are used (never this scene's map, never positions). Ties
    go to the lower class id; a macro-class absent from all other maps gets its first member.
    """
    counts = np.zeros(N_CLASSES, dtype=int)
    for cl in other_scene_classes:
        cl = np.asarray(cl, int)
        counts += np.bincount(cl[(cl >= 0) & (cl < N_CLASSES)], minlength=N_CLASSES)
    prior = {}
    for m in MACRO_CLASSES:
        members = np.array(m.classes)
        prior[m.name] = int(members[np.argmax(counts[members])]) if counts[members].any() else int(members[0])
    return prior


def objects_reference_map(
    objects: pd.DataFrame, transformations: dict, frame: geo.MetricFrame, prior: dict[str, int] | None = None
) -> pd.DataFrame:
    """Our objects as a reference map: lon/lat (published chain) + metric x/y + a 42-class label.

    Positions come only from our clustered centroids pushed through the chain; ``prior`` (from
    :func:`class_prior`) names the 42-class given to each macro-class (-1 / '' without one).
    """
    cen = objects[["cx", "cy", "cz"]].to_numpy(float).reshape(-1, 3)
    lonlat = geo.sfm_to_lonlat(cen, transformations) if len(cen) else np.zeros((0, 2))
    xy = frame.to_xy(lonlat) if len(cen) else np.zeros((0, 2))
    prior = prior or {}
    cid = np.array([prior.get(m, -1) for m in objects["macro_class"]], dtype=np.int64)
    return pd.DataFrame(
        {
            "object_id": objects["object_id"].to_numpy(np.int64),
            "macro_class": objects["macro_class"].astype(str).to_numpy(),
            "class_id": cid,
            "class_label": [CLASSES[c] if c >= 0 else "" for c in cid],
            "n_points": objects["n_points"].to_numpy(np.int64),
            "lon": lonlat[:, 0],
            "lat": lonlat[:, 1],
            "x_m": xy[:, 0],
            "y_m": xy[:, 1],
        }
    )


NOT_AN_OBJECT = 255


def point_labels(points: pd.DataFrame) -> np.ndarray:
    """Macro-class of each classified SfM point (background for 255 / non-object classes)."""
    return macro_of_class(points["class_id"].to_numpy())


def majority_class(class_ids: np.ndarray) -> int:
    vals, counts = np.unique(np.asarray(class_ids, int), return_counts=True)
    return int(vals[np.argmax(counts)])


OBJECT_MAP_COLUMNS = [
    "scene",
    "object_id",
    "macro_class",
    "class_id",
    "class_label",
    "n_points",
    "cx",
    "cy",
    "cz",
    "lon",
    "lat",
    "x_m",
    "y_m",
]


def images_scene_objects(
    scene: str,
    points: pd.DataFrame,
    alignment: dict,
    params: clustering.ClusterParams,
    class_labels: list[str],
    source: str = "points",
    instances: pd.DataFrame | None = None,
) -> tuple[pd.DataFrame, np.ndarray]:
    """Cluster the classified SfM points of an images scene into objects on the aligned map.

    Returns (objects with box columns, 42-class label and lon/lat/x/y; object id per point); in a
    local-frame alignment (no GPS) x_m/y_m are in its unit and lon/lat are NaN.
    With ``instances`` (:func:`flatlandia.images.classify_points.point_instances`), each cluster is split into
    the image instances its points were seen on (:func:`flatlandia.objects.clustering.instance_parts`).
    A model without object points gives an empty table: a documented outcome (e.g. the
    offline segmentation backend labels no object classes), not an error.
    """
    xyz = points[["x", "y", "z"]].to_numpy(float)
    labels = point_labels(points)
    if not (labels != BACKGROUND).any():
        empty = pd.DataFrame(
            columns=OBJECT_MAP_COLUMNS + [c for c in clustering.OBJECT_COLUMNS if c not in OBJECT_MAP_COLUMNS]
        )
        return empty, np.full(len(points), -1, np.int64)
    split = None
    if instances is not None and len(instances):
        index = pd.Series(np.arange(len(points)), index=points["point3D_id"].to_numpy(np.int64))
        known = instances["point3D_id"].isin(index.index).to_numpy()
        obs_point = index.loc[instances.loc[known, "point3D_id"]].to_numpy()
        obs_key = instances.loc[known, "key"].to_numpy(np.int64)

        def split(members: np.ndarray) -> list[np.ndarray]:
            return clustering.instance_parts(members, xyz, obs_point, obs_key, params.min_cluster_points)

    objs, member = clustering.cluster_objects(
        xyz, labels, float(alignment["metres_per_sfm_unit"]), params, source=source, split=split, with_members=True
    )
    cls = points["class_id"].to_numpy(int)
    objs["class_id"] = [
        majority_class(cls[member == oid]) if (member == oid).any() else NOT_AN_OBJECT for oid in objs["object_id"]
    ]
    objs["class_label"] = [class_labels[c] if c < len(class_labels) else "" for c in objs["class_id"]]
    xy = geo.alignment_points(alignment, objs[["cx", "cy", "cz"]].to_numpy())
    ll = geo.alignment_lonlat(alignment, xy)  # NaN in a local frame (no GPS)
    objs["lon"], objs["lat"], objs["x_m"], objs["y_m"] = ll[:, 0], ll[:, 1], xy[:, 0], xy[:, 1]
    objs.insert(0, "scene", scene)
    rest = [c for c in objs.columns if c not in OBJECT_MAP_COLUMNS]
    return objs[OBJECT_MAP_COLUMNS + rest].reset_index(drop=True), member
