"""Classify SfM points: each 3D point takes the majority object class of its 2D observations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from PIL import Image

from flatlandia.images.segment import NOT_AN_OBJECT
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.names import child, plain_name


def point_votes(rec, class_maps: dict[str, np.ndarray]) -> pd.DataFrame:
    """One row per 3D point: xyz, majority Flatlandia class (255 = background), votes, observations.

    A point is an object point when the majority of its *labelled-image* observations fall on
    pixels of one class; ties and background majorities give 255.
    """
    rows = []
    for pid, p in rec.points3D.items():
        labels = []
        for el in p.track.elements:
            img = rec.images[el.image_id]
            cmap = class_maps.get(img.name)
            if cmap is None:
                continue
            x, y = img.points2D[el.point2D_idx].xy
            r, c = (
                int(np.clip(round(y - 0.5), 0, cmap.shape[0] - 1)),
                int(np.clip(round(x - 0.5), 0, cmap.shape[1] - 1)),
            )
            labels.append(int(cmap[r, c]))
        cls, votes = NOT_AN_OBJECT, 0
        if labels:
            vals, counts = np.unique(labels, return_counts=True)
            order = np.argsort(-counts)
            top = counts[order[0]]
            if top * 2 > len(labels) and (len(order) == 1 or counts[order[1]] < top):
                cls, votes = int(vals[order[0]]), int(top)
        rows.append(
            {
                "point3D_id": int(pid),
                "x": p.xyz[0],
                "y": p.xyz[1],
                "z": p.xyz[2],
                "class_id": cls,
                "votes": votes,
                "observations": len(labels),
            }
        )
    return pd.DataFrame(rows)


def point_instances(rec, instance_maps: dict[str, np.ndarray]) -> pd.DataFrame:
    """One row per 2D observation of a 3D point on an instance (id > 0) of an instance map.

    ``instance_maps``: image name -> (H, W) integer instance ids, 0 = no instance (e.g. the
    things of a panoptic segmentation). ``key`` is unique per (image, instance), so points can
    be grouped by the instance they were seen on (:func:`flatlandia.objects.clustering.instance_parts`).
    """
    rows = []
    for image_id, img in rec.images.items():
        imap = instance_maps.get(img.name)
        if imap is None:
            continue
        for p2 in img.points2D:
            if not p2.has_point3D():
                continue
            x, y = p2.xy
            r = int(np.clip(round(y - 0.5), 0, imap.shape[0] - 1))
            c = int(np.clip(round(x - 0.5), 0, imap.shape[1] - 1))
            inst = int(imap[r, c])
            if inst > 0:
                rows.append((int(p2.point3D_id), int(image_id), inst))
    df = pd.DataFrame(rows, columns=["point3D_id", "image_id", "instance"]).astype(np.int64)
    df["key"] = df["image_id"] * (1 << 32) + df["instance"]
    return df


def load_instance_maps(folder: str | Path | None, names: list[str]) -> dict[str, np.ndarray]:
    """Instance-id images ``<image stem>.png`` of a folder (none when ``folder`` is None).

    A folder that holds none of the model's images is a configuration error, named. Image names
    are checked plain file names: ``<stem>.png`` stays inside the folder."""
    if folder is None:
        return {}
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "segment.instances_dir is not a folder")
    maps = {}
    for n in names:
        p = child(folder, Path(plain_name(n, folder, "image name")).stem, ".png", "image name")
        if p.exists():
            with Image.open(p) as im:
                ids = np.asarray(im)
            if ids.ndim != 2:
                raise InputError(p, "instance image must be single-channel ids (0 = no instance)")
            maps[n] = ids
    if names and not maps:
        raise InputError(folder, f"no instance image <stem>.png for any of the {len(names)} images")
    return maps


def load_class_maps(folder: Path, names: list[str]) -> dict[str, np.ndarray]:
    """Class maps ``<image name>.png`` of a folder; names checked plain, so each stays inside it."""
    maps = {}
    for n in names:
        p = child(folder, n, ".png", "image name")
        if p.exists():
            with Image.open(p) as im:
                maps[n] = np.asarray(im)
    return maps


def write_classified_ply(points: pd.DataFrame, path: Path) -> None:
    """PLY of the points (x, y, z double, a colour per class, a uchar ``class_id`` property) by
    open3d's tensor writer, which keeps the extra property for CloudCompare's scalar fields.

    Binary, so coordinates keep their full precision (open3d's ASCII writer keeps 6 digits).
    """
    import open3d as o3d

    from flatlandia.plumbing.files import atomic_path

    if points.empty:
        raise ValueError(f"{path}: no points to write (open3d writes no empty PLY)")
    rng = np.random.default_rng(0)
    palette = rng.integers(40, 255, size=(256, 3)).astype(np.uint8)
    palette[NOT_AN_OBJECT] = (51, 51, 51)  # background grey, as in the published clouds
    cls = points["class_id"].to_numpy().astype(np.uint8)
    pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(points[["x", "y", "z"]].to_numpy(np.float64)))
    pc.point.colors = o3d.core.Tensor(palette[cls])
    pc.point.class_id = o3d.core.Tensor(cls[:, None])
    with atomic_path(path) as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), pc):
            raise OSError(f"open3d could not write {tmp}")
