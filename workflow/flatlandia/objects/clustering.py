"""Objects from a classified point cloud: cluster per macro-class -> 3D boxes.

Measured on the published data (docs/conventions.md, "Class clouds and reference maps"):

- A reference object is the mean of the points of one object, so the centroid we report is
  the plain mean of the cluster's points (not the box centre).
- The published procedure, measured (figures: docs/measurements.md, "Objects from the published
  clouds"): for each published object we searched the single-linkage dendrogram of its colour's 3D
  points (equivalent to DBSCAN with min_samples <= 3 at every radius) for a node whose mean is the
  object; most objects outside scene 2 are such a 3D cluster (fewer with 2D clustering of projected
  points, or with z weighted). Each object's admissible radius range, in metres through
  :func:`flatlandia.objects.cloud.metres_per_unit`, is tight and class dependent (in SfM units it
  spreads far wider, so the radius is metric); DBSCAN min_samples 1-3 give identical objects, more
  lose objects. These are the defaults of :class:`ClusterParams`.
- Splitting same-class neighbours: with images, :func:`instance_parts` splits a cluster into the
  image instances its points were seen on (the paper's check against instance masks; the images
  branch with ``segment.instances_dir``). A class cloud alone has only the extent-based
  re-clustering (``split_extent_m``, off by default).
- What is not reproduced (bounds in :mod:`flatlandia.objects.bounds`,
  ``benchmarks/reproduction_bounds.py``; figures: docs/measurements.md, "Objects from the published
  clouds"): some published objects are not a cluster at any radius (the paper splits clusters by
  reprojecting them into instance masks, which needs the images), and even the best radius per scene
  and class chosen with the answer stays below the reproduction target. The published maps drop
  clusters that the cloud cannot tell apart from kept ones (scenes 2 and 4; on scene 2 no cluster
  or SfM-track feature separates kept from dropped) - presumably objects without matched detections.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import config
from flatlandia.objects.cloud import BACKGROUND, MACRO_BY_NAME
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.files import atomic_path


@config.settings("objects.cluster", frozen=True)
class ClusterParams:
    """Clustering settings, all lengths in metres: the config section ``objects.cluster``, whose
    defaults are the measured published procedure (docs/measurements.md; each key is described in
    config/README.md, ``objects.cluster.*``).

    ``eps_m`` is the DBSCAN radius of every macro-class not named in ``eps_m_by_class``: per-class
    radii measured on the 12 published class clouds (thin poles are clustered much tighter than
    signs, lights and markings). The split of long clusters is off by default (``split_extent_m``
    None): the published objects are plain single-radius clusters, and re-clustering long ones
    lowered the reproduction.
    """

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
        if p.split_extent_m is not None and extent > p.split_extent_m and p.split_eps_factor < 1:
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


#: A PLY of no boxes, for what open3d refuses to write (an empty mesh): an images scene whose
#: points carry no object class still gets an ``objects.ply`` that viewers open.
_NO_BOXES_PLY = (
    "ply\nformat ascii 1.0\ncomment Flatlandia objects: none\nelement vertex 0\nproperty double x\n"
    "property double y\nproperty double z\nelement face 0\nproperty list uchar uint vertex_indices\nend_header\n"
)


def _boxes_mesh(objects: pd.DataFrame):
    """The boxes as one open3d triangle mesh: 8 corners + 12 triangles per box, coloured by macro-class.

    Built from :func:`box_corners` rather than ``TriangleMesh.create_from_oriented_bounding_box``,
    which refuses flat boxes (every 3-point cluster is one).
    """
    import open3d as o3d

    corners = np.vstack([box_corners(row) for row in objects.itertuples(index=False)])
    faces = np.vstack([_BOX_FACES + 8 * k for k in range(len(objects))])
    rgb = [MACRO_BY_NAME[m].rgb if m in MACRO_BY_NAME else (128, 128, 128) for m in objects["macro_class"]]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(corners), o3d.utility.Vector3iVector(faces))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.repeat(np.asarray(rgb, float) / 255.0, 8, axis=0))
    return mesh


def write_boxes_ply(objects: pd.DataFrame, path: str | Path) -> None:
    """Binary PLY of the boxes (:func:`_boxes_mesh`, written by open3d: double x/y/z, uchar colours), atomic."""
    import open3d as o3d

    with atomic_path(path) as tmp:
        if objects.empty:
            tmp.write_text(_NO_BOXES_PLY)
        elif not o3d.io.write_triangle_mesh(str(tmp), _boxes_mesh(objects), write_vertex_normals=False):
            raise OSError(f"open3d could not write {tmp}")
