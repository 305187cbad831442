"""Objects from a classified SfM point cloud: cluster per macro-class -> 3D boxes -> object map.

Measured on the published data (../shared/DATA.md and the audit in tests/test_objects.py):

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
- A reference object is the mean of the points of one object (DATA.md), so the centroid we
  report is the plain mean of the cluster's points (not the box centre).
- The published procedure, measured: for each published object we searched the single-linkage
  dendrogram of its colour's 3D points (equivalent to DBSCAN with min_samples <= 3 at every
  radius) for a node whose mean is the object to 1e-4 m: 643 of the 757 objects outside scene
  2 are such a 3D cluster (2D clustering of projected points: 480; z weighted 0.5 or 2: fewer).
  Each object's admissible radius range, in metres through :func:`metres_per_unit`, is tight
  and class dependent: signs, lights and markings 1.24 m (per scene 0.93-1.30 m; in SfM units
  the spread is 4x, so the radius is metric), poles 0.40 m, manholes and traffic lights
  0.88 m. DBSCAN min_samples 1-3 give identical objects, 4+ lose a third; every published
  object has >= 3 points. These are the defaults of :class:`ClusterParams`.
- Splitting same-class neighbours: with images, :func:`instance_parts` splits a cluster into the
  image instances its points were seen on (the paper's check against instance masks; the images
  branch with ``segment.instances_dir``). A class cloud alone has only the extent-based
  re-clustering (``split_extent_m``, off by default).
- What is not reproduced (bounds in :mod:`flatlandia.objects.bounds`,
  ``benchmarks/reproduction_bounds.py``): 152 published objects are not a cluster at any radius
  (the paper splits clusters by reprojecting them into instance masks, which needs the images);
  even the best radius per scene and class chosen with the answer reaches 87.5 % within 0.5 m.
  The published maps drop clusters that the cloud cannot tell apart from kept ones (scene 4:
  166 clusters, 158 published boxes, 73 objects; scene 2's cloud is 99.7% coloured, 511
  published boxes, 97 objects; on scene 2 no cluster or SfM-track feature separates kept from
  dropped, ROC AUC 0.47-0.65) - presumably objects without matched detections.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES, N_CLASSES
from flatlandia.errors import InputError
from flatlandia.io import atomic_path

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


# --------------------------------------------------------------------------- clustering


#: Per-class DBSCAN radius (m) measured on the 12 published class clouds (see module doc):
#: thin poles are clustered much tighter than signs, lights and markings.
DEFAULT_EPS_BY_CLASS = {"pole": 0.40, "manhole": 0.88, "traffic_light": 0.88}


@dataclass(frozen=True)
class ClusterParams:
    """Clustering settings, all lengths in metres (defaults = the measured published procedure).

    ``eps_m`` is the radius of every macro-class not named in ``eps_m_by_class``. The split of
    long clusters is off by default (``split_extent_m`` infinite): the published objects are
    plain single-radius clusters, and re-clustering long ones lowered the reproduction.
    """

    eps_m: float = 1.24  # DBSCAN neighbourhood radius (signs, lights, markings)
    eps_m_by_class: dict = field(default_factory=lambda: dict(DEFAULT_EPS_BY_CLASS))
    min_points: int = 3  # DBSCAN core-point neighbourhood size (the point included)
    min_cluster_points: int = 3  # clusters with fewer points are dropped (not objects)
    split_extent_m: float = float("inf")  # clusters longer than this are re-clustered ...
    split_eps_factor: float = 0.5  # ... with eps * this factor (merged same-class neighbours)

    def eps_for(self, macro_class: str) -> float:
        """DBSCAN radius (m) of one macro-class."""
        return float((self.eps_m_by_class or {}).get(macro_class, self.eps_m))


def oriented_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA box of points (N>=1, 3): (centre (3,), extent (3,) full side lengths, rotation (3,3)).

    Columns of the rotation are the box axes (largest extent first), det +1; a point p of the
    box frame maps to centre + R @ p.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    mean = pts.mean(0)
    if len(pts) < 2:
        return mean, np.zeros(3), np.eye(3)
    _, _, vt = np.linalg.svd(pts - mean, full_matrices=False)
    rot = np.eye(3)
    rot[:, : vt.shape[0]] = vt.T
    if vt.shape[0] == 2:  # two points: complete the frame
        rot[:, 2] = np.cross(rot[:, 0], rot[:, 1])
    if np.linalg.det(rot) < 0:
        rot[:, 2] *= -1
    local = (pts - mean) @ rot
    lo, hi = local.min(0), local.max(0)
    centre = mean + rot @ ((lo + hi) / 2)
    return centre, hi - lo, rot


def _dbscan(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    from sklearn.cluster import DBSCAN

    return DBSCAN(eps=eps, min_samples=min_points).fit_predict(points)


def _clusters_of_class(pts: np.ndarray, mpu: float, p: ClusterParams, eps_m: float | None = None) -> list[np.ndarray]:
    """Index arrays of the objects of one macro-class (points already of that class).

    DBSCAN in 3D SfM coordinates with the radius converted to SfM units (``eps_m / mpu``).
    """
    if len(pts) == 0:
        return []
    eps_m = p.eps_m if eps_m is None else eps_m
    lab = _dbscan(pts, eps_m / mpu, p.min_points)
    out: list[np.ndarray] = []
    for k in np.unique(lab[lab >= 0]):
        idx = np.flatnonzero(lab == k)
        if len(idx) < p.min_cluster_points:
            continue
        extent = np.ptp(pts[idx], axis=0).max() * mpu if len(idx) > 1 else 0.0
        if extent > p.split_extent_m and p.split_eps_factor < 1:
            sub = _dbscan(pts[idx], eps_m * p.split_eps_factor / mpu, p.min_points)
            parts = [idx[sub == j] for j in np.unique(sub[sub >= 0])]
            parts = [q for q in parts if len(q) >= p.min_cluster_points]
            if len(parts) >= 2:
                out.extend(parts)
                continue
        out.append(idx)
    return out


OBJECT_COLUMNS = [
    "object_id",
    "macro_class",
    "n_points",
    "cx",
    "cy",
    "cz",
    "box_cx",
    "box_cy",
    "box_cz",
    "box_ex",
    "box_ey",
    "box_ez",
    *[f"box_r{i}{j}" for i in range(3) for j in range(3)],
    "extent_max_m",
]


def instance_parts(
    members: np.ndarray, points: np.ndarray, obs_point: np.ndarray, obs_key: np.ndarray, min_points: int
) -> list[np.ndarray]:
    """Split one cluster by the image instances its points were seen on (the paper checks its
    clusters against instance masks to separate neighbouring same-class objects).

    ``members``: point indices of the cluster; ``obs_point``/``obs_key``: one entry per 2D
    observation on an instance (point index, an id unique to (image, instance)). Points seen on
    one instance of one image belong together (transitively, across images); parts of at least
    ``min_points`` points become objects, every other point of the cluster joins the part of its
    nearest part point. Fewer than two such parts: the cluster stays whole.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    members = np.asarray(members, np.int64)
    sel = np.isin(obs_point, members)
    if not sel.any():
        return [members]
    pos = np.searchsorted(np.sort(members), obs_point[sel])
    order = np.argsort(members)
    local = order[pos]  # observation -> position in members
    keys, key_idx = np.unique(np.asarray(obs_key)[sel], return_inverse=True)
    n = len(members)
    graph = coo_matrix((np.ones(len(local)), (local, n + key_idx)), shape=(n + len(keys), n + len(keys)))
    _, comp = connected_components(graph, directed=False)
    seen = np.zeros(n, bool)
    seen[local] = True
    labels, counts = np.unique(comp[:n][seen], return_counts=True)
    big = labels[counts >= min_points]
    if len(big) < 2:
        return [members]
    in_big = seen & np.isin(comp[:n], big)
    pts = np.asarray(points, float)[members]
    owner = comp[:n].copy()
    rest = ~in_big
    if rest.any():
        _, j = cKDTree(pts[in_big]).query(pts[rest])
        owner[rest] = comp[:n][in_big][j]
    return [members[owner == b] for b in big]


def cluster_objects(
    points: np.ndarray,
    labels: np.ndarray,
    metres_per_unit: float,
    params: ClusterParams | None = None,
    source: str = "cloud",
    split=None,
    with_members: bool = False,
) -> pd.DataFrame | tuple[pd.DataFrame, np.ndarray]:
    """Cluster each macro-class separately into objects; one row per object (SfM coordinates).

    ``split`` (optional): indices of one cluster's points -> list of index arrays, its objects
    (e.g. :func:`instance_parts` bound to the images' instance observations).
    ``with_members``: also return the object id of every point (-1: in no object).

    Raises :class:`InputError` (naming ``source``) for NaN coordinates, a non-positive scale or a
    cloud without classified points. A class whose points all fall in clusters smaller than
    ``min_cluster_points`` (e.g. a single point) yields no object: that is a documented empty
    result for the class, not an error.
    """
    p = params or ClusterParams()
    pts = np.asarray(points, float)
    labels = np.asarray(labels, dtype=object).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) != len(labels):
        raise InputError(source, f"points must be (N, 3) with one label each, got {pts.shape} and {labels.shape}")
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts).all(1)).sum())
        raise InputError(source, f"{bad} point(s) with NaN/inf coordinates")
    if not (np.isfinite(metres_per_unit) and metres_per_unit > 0):
        raise InputError(source, f"metres per SfM unit must be positive, got {metres_per_unit}")
    if (
        p.min_points < 1
        or p.min_cluster_points < 1
        or not all(np.isfinite(e) and e > 0 for e in [p.eps_m, *(p.eps_m_by_class or {}).values()])
    ):
        raise ValueError(f"bad clustering parameters {p}")
    fg = labels != BACKGROUND
    if not fg.any():
        raise InputError(source, f"no classified points: all {len(pts)} points are background")
    rows = []
    member = np.full(len(pts), -1, np.int64)
    for name in sorted(set(labels[fg])):
        cls_idx = np.flatnonzero(labels == name)
        clusters = [cls_idx[idx] for idx in _clusters_of_class(pts[cls_idx], metres_per_unit, p, p.eps_for(name))]
        if split is not None:
            clusters = [part for c in clusters for part in split(c)]
        for members in clusters:
            member[members] = len(rows)
            sub = pts[members]
            c, e, r = oriented_box(sub)
            m = sub.mean(0)
            rows.append([name, len(sub), *m, *c, *e, *r.reshape(-1), float(e.max() * metres_per_unit)])
    df = pd.DataFrame(rows, columns=OBJECT_COLUMNS[1:])
    df.insert(0, "object_id", np.arange(len(df), dtype=np.int64))
    df["n_points"] = df["n_points"].astype(np.int64)
    return (df, member) if with_members else df


def box_corners(row) -> np.ndarray:
    """The 8 corners (8, 3) of an object's box (open3d's corner order is not needed by viewers)."""
    c = np.array([row.box_cx, row.box_cy, row.box_cz])
    e = np.array([row.box_ex, row.box_ey, row.box_ez]) / 2
    r = np.array([[getattr(row, f"box_r{i}{j}") for j in range(3)] for i in range(3)])
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return c + (signs * e) @ r.T


#: 12 triangles of a box over the corner order of :func:`box_corners` (index = 4*sx + 2*sy + sz).
_BOX_FACES = np.array(
    [
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ]
)


def write_boxes_ply(objects: pd.DataFrame, path: str | Path) -> None:
    """Binary PLY of the boxes (8 vertices + 12 triangles each, coloured by macro-class), atomic."""
    n = len(objects)
    vdt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    fdt = np.dtype([("n", "u1"), ("v", "<u4", (3,))])
    verts = np.zeros(8 * n, vdt)
    faces = np.zeros(12 * n, fdt)
    for k, row in enumerate(objects.itertuples(index=False)):
        corners = box_corners(row)
        rgb = MACRO_BY_NAME[row.macro_class].rgb if row.macro_class in MACRO_BY_NAME else (128, 128, 128)
        sl = slice(8 * k, 8 * k + 8)
        verts["x"][sl], verts["y"][sl], verts["z"][sl] = corners.T
        verts["red"][sl], verts["green"][sl], verts["blue"][sl] = rgb
        faces["n"][12 * k : 12 * k + 12] = 3
        faces["v"][12 * k : 12 * k + 12] = _BOX_FACES + 8 * k
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment Flatlandia objects: 8 vertices + 12 triangles per box\n"
        f"element vertex {8 * n}\nproperty double x\nproperty double y\nproperty double z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {12 * n}\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(verts.tobytes())
            f.write(faces.tobytes())


# --------------------------------------------------------------------------- labels and maps


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


# --------------------------------------------------------------------------- reproduction audit

AUDIT_THRESHOLDS_M = (0.05, 0.5, 2.0)


def published_macro_classes(
    ref_xy: np.ndarray,
    ref_classes: np.ndarray,
    cloud_xy: np.ndarray | None = None,
    cloud_labels: np.ndarray | None = None,
    max_dist_m: float = 2.0,
    cloud_points: np.ndarray | None = None,
    exact_radius: float | None = None,
) -> np.ndarray:
    """Macro-class of each published object: the label of the nearest classified cloud point
    (the objects were made from those points) when one lies within ``max_dist_m``, else the
    macro-class of its 42-class label. With ``cloud_points`` (the same points in SfM
    coordinates) and ``exact_radius`` (SfM units), an object that is the exact mean of a
    single-linkage cluster of one colour takes that colour (its nearest point can be of another:
    scene 2, 16 of 97 objects)."""
    out = macro_of_class(ref_classes)
    if cloud_xy is not None and cloud_labels is not None:
        from scipy.spatial import cKDTree

        fg = np.asarray(cloud_labels, dtype=object) != BACKGROUND
        if fg.any():
            d, j = cKDTree(np.asarray(cloud_xy)[fg]).query(ref_xy)
            near = d <= max_dist_m
            out[near] = np.asarray(cloud_labels, dtype=object)[fg][j[near]]
        if cloud_points is not None and exact_radius is not None:
            from flatlandia.objects.bounds import published_colours

            out = published_colours(
                ref_xy, out, np.asarray(cloud_points, float), cloud_labels, np.asarray(cloud_xy, float), exact_radius
            )
    return out


#: Largest clustering radius (m) searched for the published object an audit object is the mean of.
EXACT_SEARCH_RADIUS_M = 2.5


def audit_scene(
    scene: str,
    ours_xy: np.ndarray,
    ours_macro: np.ndarray,
    ref_xy: np.ndarray,
    ref_macro: np.ndarray,
    radius_m: float = 2.0,
    thresholds: tuple[float, ...] = AUDIT_THRESHOLDS_M,
) -> dict:
    """Match our objects to the published ones (same macro-class, Hungarian on metric distance,
    pairs farther than ``radius_m`` never match) and count the matches within each threshold."""
    from scipy.optimize import linear_sum_assignment

    ours_xy, ref_xy = np.asarray(ours_xy, float).reshape(-1, 2), np.asarray(ref_xy, float).reshape(-1, 2)
    ours_macro, ref_macro = np.asarray(ours_macro, dtype=object), np.asarray(ref_macro, dtype=object)
    dists = []
    for name in sorted(set(ref_macro) | set(ours_macro)):
        a, b = np.flatnonzero(ref_macro == name), np.flatnonzero(ours_macro == name)
        if len(a) == 0 or len(b) == 0:
            continue
        d = np.linalg.norm(ref_xy[a, None] - ours_xy[None, b], axis=2)
        big = radius_m * 10 + d.max() + 1
        r, c = linear_sum_assignment(np.where(d <= radius_m, d, big))
        ok = d[r, c] <= radius_m
        dists.extend(d[r[ok], c[ok]])
    dists = np.array(dists)
    row = {"scene": str(scene), "published": int(len(ref_xy)), "ours": int(len(ours_xy)), "matched": int(len(dists))}
    for t in thresholds:
        row[f"within_{t:g}m"] = int((dists <= t).sum())
    row["median_dist_m"] = float(np.median(dists)) if len(dists) else float("nan")
    t_mid = thresholds[1] if len(thresholds) > 1 else thresholds[0]
    row["extra"] = int(len(ours_xy) - (dists <= t_mid).sum())
    row["frac_within_0.5m"] = row.get("within_0.5m", 0) / max(1, len(ref_xy))
    return row


def plot_audit(ours_xy: np.ndarray, ref_xy: np.ndarray, path: str | Path, title: str) -> None:
    """Ours over theirs, in metres."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7), dpi=100)
    ax.scatter(ref_xy[:, 0], ref_xy[:, 1], s=40, facecolor="none", edgecolor="k", label=f"published ({len(ref_xy)})")
    ax.scatter(ours_xy[:, 0], ours_xy[:, 1], s=8, color="tab:red", label=f"ours ({len(ours_xy)})")
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(title)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)


def audit_published_scene(
    root: str | Path, scene: str, params: ClusterParams | None = None
) -> tuple[dict, pd.DataFrame]:
    """Run the whole chain on one published scene and audit it (used by tests and the audit rule)."""
    from flatlandia import io

    root = Path(root)
    pts, labels = read_classified_cloud(root / "maps" / scene / "class_segmented_point_cloud.ply")
    t = io.read_transformations(root / "maps" / scene / "transformations.json")
    ref_ll, ref_cl = io.read_reference_map(root / "individual_reference_maps" / f"map_{scene}.json")
    frame = geo.frame_for(ref_ll)  # frame only; no published position places an object
    objs = cluster_objects(pts, labels, metres_per_unit(t), params, source=str(root / "maps" / scene))
    ours = objects_reference_map(objs, t, frame)
    fg = labels != BACKGROUND
    cloud_xy = frame.to_xy(geo.sfm_to_lonlat(pts[fg], t))
    ref_xy = frame.to_xy(ref_ll)
    ref_macro = published_macro_classes(
        ref_xy,
        ref_cl,
        cloud_xy,
        labels[fg],
        cloud_points=pts[fg],
        exact_radius=EXACT_SEARCH_RADIUS_M / metres_per_unit(t),
    )
    row = audit_scene(scene, ours[["x_m", "y_m"]].to_numpy(), ours["macro_class"].to_numpy(), ref_xy, ref_macro)
    return row, ours


def plot_audit_grid(panels: list[tuple[str, np.ndarray, np.ndarray]], path: str | Path) -> None:
    """One panel per scene: (title, ours_xy, published_xy), ours (red dots) over theirs (circles)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(1, len(panels))
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows), dpi=90, squeeze=False)
    for ax in axes.ravel():
        ax.set_visible(False)
    for ax, (title, ours_xy, ref_xy) in zip(axes.ravel(), panels):
        ax.set_visible(True)
        ax.scatter(
            ref_xy[:, 0], ref_xy[:, 1], s=30, facecolor="none", edgecolor="k", label=f"published ({len(ref_xy)})"
        )
        ax.scatter(ours_xy[:, 0], ours_xy[:, 1], s=5, color="tab:red", label=f"ours ({len(ours_xy)})")
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=6)
        ax.tick_params(labelsize=6)
    fig.supxlabel("x east (m)")
    fig.supylabel("y north (m)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
