"""The objects stage's entry functions: one scene's classified points -> its objects table.

Rule ``objects`` (workflow/scripts/objects.py) reads the inputs, calls :func:`published_objects`
or :func:`images_objects` and writes what they return; ``benchmarks/bench_objects.py`` and
:func:`flatlandia.objects.audit.audit_published_scene` call :func:`published_objects` too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.objects import cloud, clustering, labels


@dataclass
class SceneObjects:
    """What rule objects writes: ``objects`` (objects.parquet with ``meta``; its boxes go to the
    PLY), ``members`` (point -> object, point_objects.parquet with ``members_meta``) and a one-line
    ``summary`` for the log."""

    objects: pd.DataFrame
    meta: dict
    members: pd.DataFrame
    members_meta: dict
    summary: str


def published_objects(
    scene: str,
    points: np.ndarray,
    point_labels: np.ndarray,
    transformations: dict,
    reference_lonlat: np.ndarray,
    other_classes: list[np.ndarray],
    cluster: dict,
    source: str = "cloud",
) -> SceneObjects:
    """A published scene's objects: clusters of its class point cloud (``points``, macro-class
    ``point_labels``, :func:`flatlandia.objects.cloud.read_classified_cloud`), placed through the
    published chain (``transformations``) in the metric frame of the published map (only its
    origin, from ``reference_lonlat``), each labelled with the 42-class most frequent for its
    macro-class among ``other_classes`` (the other scenes' map labels; never this scene's).
    ``cluster`` is the config's objects.cluster section."""
    params = clustering.ClusterParams.from_dict(cluster)
    mpu = cloud.metres_per_unit(transformations)
    objs, member = clustering.cluster_objects(points, point_labels, mpu, params, source=source, with_members=True)
    prior = labels.class_prior(other_classes)
    frame = geo.frame_for(reference_lonlat)  # the scene's metric frame (origin only), as every other stage's
    ref = labels.objects_reference_map(objs, transformations, frame, prior)
    table = objs.merge(ref.drop(columns=["macro_class", "n_points"]), on="object_id")
    table.insert(0, "scene", scene)
    meta = {
        "scene": scene,
        "crs": frame.proj4,
        "lon0": frame.lon0,
        "lat0": frame.lat0,
        "metres_per_sfm_unit": mpu,
        "cluster_params": dict(cluster),
        "coordinates": "cx/cy/cz, box_* in SfM units; lon/lat via the published chain; x_m/y_m metric frame",
        "label_transfer": "per macro-class the most frequent 42-class among the other scenes' published maps",
        "class_prior": prior,
    }
    in_object = np.flatnonzero(member >= 0)
    members = pd.DataFrame({"point_index": in_object.astype(np.int64), "object_id": member[in_object]})
    members_meta = {"scene": scene, "point_index": "vertex row of the class cloud; points in no object are left out"}
    summary = (
        f"scene {scene}: {int((np.asarray(point_labels) != cloud.BACKGROUND).sum())} classified of {len(points)} "
        f"points, {len(objs)} objects ({objs['macro_class'].value_counts().to_dict()}), {mpu:.4f} m per SfM unit"
    )
    return SceneObjects(table, meta, members, members_meta, summary)


#: why an images scene without object points has no objects (metadata ``empty_because``)
NO_OBJECT_POINTS = (
    "no SfM point carries an object class (e.g. the offline segmentation backend "
    "labels none): no objects, hence an empty reference map and no queries"
)


def images_objects(
    scene: str,
    points: pd.DataFrame,
    alignment: dict,
    instances: pd.DataFrame,
    cluster: dict,
    source: str = "points",
) -> SceneObjects:
    """An images scene's objects: clusters of its classified SfM ``points`` (rule classify_points),
    split by the image ``instances`` their points fall on, labelled with their points' majority
    42-class and placed through the scene's GPS ``alignment`` (rule gps_alignment; a local frame
    without GPS gives x_m/y_m in its unit and no lon/lat). No object point: an empty table whose
    metadata says why (``empty_because``)."""
    params = clustering.ClusterParams.from_dict(cluster)
    objs, member = labels.images_scene_objects(
        scene, points, alignment, params, CLASSES, source=source, instances=instances
    )
    local = geo.alignment_is_local(alignment)
    meta = {
        "scene": scene,
        "frame": "local" if local else "gps",
        "crs": alignment["crs"],
        "lon0": alignment["frame_lon0"],
        "lat0": alignment["frame_lat0"],
        "unit": alignment.get("unit", "m"),
        "metres_per_sfm_unit": alignment["metres_per_sfm_unit"],
        "cluster_params": dict(cluster),
        "coordinates": (
            "cx/cy/cz, box_* in SfM units; x_m/y_m on the SfM ground plane in the local frame's unit; no lon/lat"
            if local
            else "cx/cy/cz, box_* in SfM units; x_m/y_m metric frame of the GPS alignment; lon/lat WGS84"
        ),
        "label": "majority 42-class of the object's points",
        "instance_split": bool(len(instances)),
    }  # clusters split by the image instances their points fall on
    if objs.empty:
        meta["empty_because"] = NO_OBJECT_POINTS
    members = pd.DataFrame({"point3D_id": points["point3D_id"].to_numpy(np.int64), "object_id": member})
    summary = (
        f"scene {scene}: {int((member >= 0).sum())} object points, {len(objs)} objects "
        f"{objs['class_label'].value_counts().to_dict() if len(objs) else {}}"
    )
    return SceneObjects(objs, meta, members, {"scene": scene}, summary)
