"""The published class point clouds: PLY reading, the colour -> macro-class table, metric scale.

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

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.errors import InputError

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
        _ids(
            "driveway",
            "marking--discrete--arrow--left",
            "marking--discrete--arrow--right",
            "marking--discrete--arrow--split-left-or-straight",
            "marking--discrete--arrow--split-right-or-straight",
            "marking--discrete--arrow--straight",
            "crosswalk-plain",
            "crosswalk-zebra",
            "give-way-row",
            "give-way-single",
            "stop-line",
            "marking--discrete--symbol--bicycle",
            "marking--discrete--text",
            "other-marking",
            "object--trash-can",
        ),
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

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


def _read_ply_vertices(path: Path) -> pd.DataFrame:
    """The vertex element of a PLY file (ascii or binary little/big endian) as a DataFrame."""
    if not path.exists():
        raise InputError(path, "file is missing")
    raw = path.read_bytes()
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError(path, "not a PLY file (no 'ply' magic or no end_header)")
    nl = raw.find(b"\n", end)
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    body = raw[nl + 1 :]
    fmt, elements, current = None, [], None
    for line in header:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            current = {"name": tok[1], "count": int(tok[2]), "props": []}
            elements.append(current)
        elif tok[0] == "property" and current is not None:
            if tok[1] == "list":
                current["props"].append((tok[4], "list", tok[2], tok[3]))
            else:
                if tok[1] not in _PLY_TYPES:
                    raise InputError(path, f"unsupported PLY property type {tok[1]!r}")
                current["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if not elements or elements[0]["name"] != "vertex":
        raise InputError(path, "PLY has no leading 'vertex' element")
    vert = elements[0]
    if any(p[1] == "list" for p in vert["props"]):
        raise InputError(path, "list properties on vertices are not supported")
    names = [p[0] for p in vert["props"]]
    for need in ("x", "y", "z"):
        if need not in names:
            raise InputError(path, f"PLY vertices lack property {need!r} (have {names})")
    n = vert["count"]
    if fmt == "ascii":
        lines = body.decode("ascii", errors="replace").split("\n")[:n]
        try:
            arr = np.array([[float(v) for v in ln.split()[: len(names)]] for ln in lines], dtype=float)
        except ValueError as e:
            raise InputError(path, f"malformed ASCII vertex line ({e})") from e
        if arr.shape != (n, len(names)):
            raise InputError(path, f"header promises {n} vertices, found {len(arr)} complete lines")
        return pd.DataFrame(arr, columns=names)
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"unsupported PLY format {fmt!r}")
    order = "<" if fmt == "binary_little_endian" else ">"
    dt = np.dtype([(p[0], order + p[1]) for p in vert["props"]])
    if len(body) < n * dt.itemsize:
        raise InputError(path, f"truncated: {n} vertices need {n * dt.itemsize} bytes, file has {len(body)}")
    v = np.frombuffer(body, dtype=dt, count=n)
    return pd.DataFrame({k: v[k].astype(float) for k in names})


def read_classified_cloud(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a classified point cloud -> (points (N, 3) float, macro-class label (N,) object array).

    Two kinds are understood: the published class clouds (colour = macro-class, grey (51,51,51)
    background) and our own clouds with an integer ``class_id`` vertex property (42-class id,
    255 background), whose classes are folded into macro-classes. Unknown colours raise.
    """
    path = Path(path)
    v = _read_ply_vertices(path)
    pts = v[["x", "y", "z"]].to_numpy(float)
    if "class_id" in v.columns:
        labels = macro_of_class(v["class_id"].to_numpy().astype(int))
    else:
        cols = [c for c in ("red", "green", "blue") if c in v.columns]
        if len(cols) != 3:
            raise InputError(path, "PLY has neither a class_id property nor red/green/blue colours")
        rgb = v[cols].to_numpy().astype(int)
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
