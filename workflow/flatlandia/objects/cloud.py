"""The published class point clouds: PLY reading (open3d), the colour -> macro-class table, metric scale.

Measured on the published data (docs/conventions.md, "Class clouds and reference maps"; the
audit in tests/test_objects.py):

- The published ``class_segmented_point_cloud.ply`` files colour points by 6 *macro-classes*
  (grey (51, 51, 51) is background). Which of the 42 classes each colour holds was measured by
  taking, for every published reference object of the 12 scenes with a class cloud, the colour
  of the nearest non-grey cloud point (854 objects). :data:`MACRO_CLASSES` lists, per colour,
  the classes whose majority fell on it (e.g. street-light: yellow 119, magenta 12, red 4);
  classes never seen in a class-cloud scene are placed by meaning (a marking with the markings,
  a traffic light with the traffic lights). :func:`colour_class_counts` redoes the measurement.
- Clustering runs in metres: one SfM unit is ``s`` degrees (``scaling_factor_sfm_to_gps`` of
  the published chain, isotropic in degrees), and one degree of latitude is about
  :data:`METRES_PER_DEGREE` m, so ``metres_per_unit = s * 111320`` (the east-west direction of
  the published chain is off by cos(lat) anyway; the clustering uses the latitude scale).
"""

from __future__ import annotations

import re
from contextlib import redirect_stdout
from dataclasses import dataclass
from io import StringIO
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES, MARKINGS
from flatlandia.plumbing import ply
from flatlandia.plumbing.errors import InputError

#: Metres per degree of latitude (mean, WGS84); used to turn the chain's scale into metres.
METRES_PER_DEGREE = 111_320.0
#: Colour of background points in the published class clouds.
BACKGROUND_RGB = (51, 51, 51)
#: Label given to background points.
BACKGROUND = ""


@dataclass(frozen=True)
class MacroClass:
    name: str
    rgb: tuple[int, int, int]
    classes: tuple[int, ...]  # ids into classes.CLASSES


def _ids(*labels: str) -> tuple[int, ...]:
    return tuple(CLASSES.index(lab) for lab in labels)


#: Colour -> macro-class -> member classes (measured majority colour per class, see module doc).
MACRO_CLASSES: tuple[MacroClass, ...] = (
    MacroClass("light", (255, 255, 0), _ids("object--street-light")),
    MacroClass("manhole", (255, 255, 255), _ids("object--manhole")),
    MacroClass(
        "sign",
        (255, 0, 0),
        _ids(
            "banner",
            "object--sign--advertisement",
            "object--sign--information",
            "object--sign--store",
            "object--traffic-sign",
            "object--traffic-sign--direction",
            "object--bench",
        ),
    ),
    MacroClass(
        "traffic_light",
        (0, 0, 255),
        _ids(
            "object--traffic-sign--information-parking",
            "object--traffic-light--general-upright",
            "object--traffic-light--general-horizontal",
            "object--traffic-light--general-single",
            "object--traffic-light--general-other",
            "object--traffic-light--pedestrians",
            "object--traffic-light--cyclists",
        ),
    ),
    MacroClass(
        "pole",
        (255, 0, 255),
        _ids(
            "object--support--traffic-sign-frame",
            "object--support--pole",
            "object--junction-box",
            "object--water-valve",
            "object--bike-rack",
            "object--catch-basin",
            "object--cctv-camera",
            "object--fire-hydrant",
            "object--mailbox",
            "object--parking-meter",
            "object--phone-booth",
        ),
    ),
    MacroClass(
        "marking_trash",
        (0, 255, 0),
        _ids(*MARKINGS, "object--trash-can"),
    ),
)
MACRO_BY_RGB = {m.rgb: m for m in MACRO_CLASSES}
MACRO_BY_NAME = {m.name: m for m in MACRO_CLASSES}
#: 42-class id -> macro-class name.
MACRO_OF_CLASS = {c: m.name for m in MACRO_CLASSES for c in m.classes}


def macro_of_class(class_ids: np.ndarray) -> np.ndarray:
    """Macro-class name of each 42-class id (background label for 255 / unknown ids)."""
    return np.array([MACRO_OF_CLASS.get(int(c), BACKGROUND) for c in np.asarray(class_ids).reshape(-1)], dtype=object)


def metres_per_unit(transformations: dict) -> float:
    """Metres per SfM unit implied by the published chain's degree scale."""
    return float(transformations["to_mapillary"]["scaling_factor_sfm_to_gps"]) * METRES_PER_DEGREE


# --------------------------------------------------------------------------- PLY reading


def _read_ply_vertices(path: Path) -> dict[str, np.ndarray]:
    """Vertex attributes of a PLY file (ascii or binary) by open3d's tensor reader, which keeps
    custom properties such as ``class_id`` with their PLY type (``positions``, ``colors``, ...).

    Open3D reports a failed read (not a PLY, a truncated body) only in its log, which its Python
    binding prints to ``sys.stdout``: the log is captured so such a file raises instead of
    yielding garbage.
    """
    import open3d as o3d

    ply.check_header(path)  # counts the body cannot hold are refused before open3d allocates
    log = StringIO()
    with redirect_stdout(log), o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Warning):
        pc = o3d.t.io.read_point_cloud(str(path), format="ply")
    failed = re.findall(r"Read PLY failed[^\x1b\n]*", log.getvalue())
    if failed or "positions" not in pc.point:
        raise InputError(path, f"unreadable PLY ({'; '.join(failed) or 'no x/y/z vertices'})")
    return {k: pc.point[k].numpy() for k in pc.point}


def read_classified_cloud(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a classified point cloud -> (points (N, 3) float, macro-class label (N,) object array).

    Two kinds are understood: the published class clouds (colour = macro-class, grey (51,51,51)
    background) and our own clouds with an integer ``class_id`` vertex property (42-class id,
    255 background), whose classes are folded into macro-classes. Unknown colours raise.
    """
    path = Path(path)
    v = _read_ply_vertices(path)
    pts = v["positions"].astype(float)
    if "class_id" in v:
        labels = macro_of_class(v["class_id"].astype(int))
    else:
        if "colors" not in v:
            raise InputError(path, "PLY has neither a class_id property nor red/green/blue colours")
        rgb = v["colors"].astype(int)
        keys, inv = np.unique(rgb, axis=0, return_inverse=True)
        names = []
        for k in map(tuple, keys):
            if k == BACKGROUND_RGB:
                names.append(BACKGROUND)
            elif k in MACRO_BY_RGB:
                names.append(MACRO_BY_RGB[k].name)
            else:
                raise InputError(
                    path,
                    f"colour {k} is neither background {BACKGROUND_RGB} nor a macro-class "
                    f"colour {sorted(MACRO_BY_RGB)}",
                )
        labels = np.array(names, dtype=object)[inv.reshape(-1)]
    return pts, labels


def colour_class_counts(
    cloud_lonlat: np.ndarray,
    cloud_labels: np.ndarray,
    ref_lonlat: np.ndarray,
    ref_classes: np.ndarray,
    frame: geo.MetricFrame,
) -> pd.DataFrame:
    """Measure the colour <-> class relation: macro-class of the nearest classified point per object.

    Returns one row per (class_id, macro_class) with a count and the median distance (m).
    """
    from scipy.spatial import cKDTree

    fg = np.asarray(cloud_labels, dtype=object) != BACKGROUND
    if not fg.any():
        raise ValueError("no classified points to measure colours on")
    tree = cKDTree(frame.to_xy(np.asarray(cloud_lonlat)[fg]))
    d, j = tree.query(frame.to_xy(ref_lonlat))
    df = pd.DataFrame(
        {
            "class_id": np.asarray(ref_classes, int),
            "macro_class": np.asarray(cloud_labels, dtype=object)[fg][j],
            "dist_m": d,
        }
    )
    return df.groupby(["class_id", "macro_class"], as_index=False).agg(
        count=("dist_m", "size"), median_dist_m=("dist_m", "median")
    )
