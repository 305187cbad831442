"""How close can any clustering of a published class cloud get to the published reference map?

The reproduction audit (:func:`flatlandia.objects.audit.audit_scene`) says how far our objects are from
the published ones; this module says how far *any* radius choice could get, so that a gap can be
told apart from a bad parameter. Every function here reads the published positions: they are
diagnostics for the audit and never place an object.

- :func:`single_linkage_tree`: every cluster that single linkage (= DBSCAN with min_samples <= 2,
  and on these clouds the same objects as min_samples 3) forms at some radius, with the radius
  interval over which it exists. A published object that is the exact mean of one of these
  nodes is reproducible by *some* radius; one that is not needs a split the cloud cannot tell.
- :func:`exact_objects`: which published objects are such exact nodes, and their radius interval.
- :func:`best_radius_reproduction`: the best any single radius per scene and macro-class can do
  (the radius chosen with the published answer, an oracle): an upper bound for every rule that
  picks one radius per class and scene.
- :func:`read_colmap_tracks` + :func:`cluster_features` + :func:`feature_auc`: whether anything the
  cloud and its SfM tracks know (points, images observing, track length, extent) separates the
  clusters a published map kept from those it dropped.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.plumbing.errors import InputError


@dataclass(frozen=True)
class MergeTree:
    """Nodes of a single-linkage merge tree (leaves first, then one node per merge).

    Radii are in the units of the points given to :func:`single_linkage_tree`.
    """

    mean: np.ndarray  # (n_nodes, d) mean of the node's values
    size: np.ndarray  # (n_nodes,) number of points
    born: np.ndarray  # radius at which the node forms (0 for a single point)
    dies: np.ndarray  # radius at which it merges into a larger node (inf: not below max_radius)


def single_linkage_tree(points: np.ndarray, values: np.ndarray, max_radius: float) -> MergeTree:
    """Single-linkage merge tree of ``points`` (N, 3), exact for every merge up to ``max_radius``.

    ``values`` (N, d) are averaged per node (e.g. the points' metric map coordinates, so a
    node's mean can be compared with a published object). Kruskal over the radius graph.
    """
    from scipy.sparse.csgraph import minimum_spanning_tree
    from scipy.spatial import cKDTree

    pts = np.asarray(points, float).reshape(-1, 3)
    vals = np.asarray(values, float).reshape(len(pts), -1)
    n = len(pts)
    mean, size = [v for v in vals], [1] * n
    born, dies = [0.0] * n, [np.inf] * n
    if n >= 2:
        graph = cKDTree(pts).sparse_distance_matrix(cKDTree(pts), max_radius, output_type="coo_matrix")
        graph.data = graph.data + 1e-300  # duplicate points: keep their zero-length edge
        mst = minimum_spanning_tree(graph.tocsr()).tocoo()
        order = np.argsort(mst.data, kind="stable")
        parent = np.arange(n)
        node = np.arange(n)  # root point -> its current node id

        def root(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        for e in order:
            a, b = root(mst.row[e]), root(mst.col[e])
            if a == b:
                continue
            h = float(mst.data[e])
            na, nb = node[a], node[b]
            dies[na] = dies[nb] = h
            size.append(size[na] + size[nb])
            mean.append((mean[na] * size[na] + mean[nb] * size[nb]) / size[-1])
            born.append(h)
            dies.append(np.inf)
            parent[b] = a
            node[a] = len(size) - 1
    return MergeTree(
        np.asarray(mean, float).reshape(len(size), vals.shape[1]), np.asarray(size), np.asarray(born), np.asarray(dies)
    )


def exact_objects(tree: MergeTree, ref_xy: np.ndarray, tol: float = 1e-3, min_size: int = 3) -> pd.DataFrame:
    """Per published object: distance to the nearest node of at least ``min_size`` points, whether
    that is exact (within ``tol``, same units as the values) and the node's radius interval."""
    from scipy.spatial import cKDTree

    ref_xy = np.asarray(ref_xy, float).reshape(-1, tree.mean.shape[1])
    keep = np.flatnonzero(tree.size >= min_size)
    out = pd.DataFrame(
        {"dist": np.full(len(ref_xy), np.inf), "exact": False, "radius_lo": np.nan, "radius_hi": np.nan, "size": 0}
    )
    if len(keep) == 0 or len(ref_xy) == 0:
        return out
    d, j = cKDTree(tree.mean[keep]).query(ref_xy)
    node = keep[j]
    out["dist"], out["exact"] = d, d <= tol
    out["radius_lo"], out["radius_hi"] = tree.born[node], tree.dies[node]
    out["size"] = tree.size[node]
    out.loc[~out["exact"], ["radius_lo", "radius_hi"]] = np.nan
    return out


def published_colours(
    ref_xy: np.ndarray,
    fallback: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    xy: np.ndarray,
    max_radius: float,
    tol: float = 1e-3,
) -> np.ndarray:
    """Macro-class (cloud colour) of each published object for the audit's same-class matching.

    A published object that is the exact mean (``tol``, metres of ``xy``) of a single-linkage
    cluster of one colour's points was made from that colour, whatever its nearest point says
    (scene 2: 16 of 97); the others keep ``fallback`` (e.g. the nearest coloured point's label).
    ``points`` (N, 3) SfM coordinates, ``labels`` their colours ("" = background), ``xy`` their
    metric map coordinates, ``max_radius`` in SfM units.
    """
    out = np.asarray(fallback, dtype=object).copy()
    best = np.full(len(out), np.inf)
    labels = np.asarray(labels, dtype=object)
    for name in sorted(set(labels) - {""}):
        ci = np.flatnonzero(labels == name)
        ex = exact_objects(single_linkage_tree(points[ci], xy[ci], max_radius), ref_xy, tol)
        better = ex["exact"].to_numpy() & (ex["dist"].to_numpy() < best)
        out[better], best[better] = name, ex["dist"].to_numpy()[better]
    return out


def best_radius_reproduction(
    cluster_means,
    ref_xy: np.ndarray,
    radii: np.ndarray,
    thresholds: tuple[float, ...] = (0.05, 0.5),
    match_radius: float = 2.0,
) -> pd.DataFrame:
    """Reproduction of one class at each radius: ``cluster_means(r)`` -> (K, 2) metric means of
    the clusters at radius ``r``; matched one-to-one (Hungarian) to ``ref_xy`` within
    ``match_radius``. One row per radius: clusters, matched within each threshold."""
    from scipy.optimize import linear_sum_assignment

    ref_xy = np.asarray(ref_xy, float).reshape(-1, 2)
    rows = []
    for r in radii:
        m = np.asarray(cluster_means(float(r)), float).reshape(-1, 2)
        row = {"radius": float(r), "clusters": len(m)}
        dd = np.zeros(0)
        if len(m) and len(ref_xy):
            d = np.linalg.norm(ref_xy[:, None] - m[None], axis=2)
            i, k = linear_sum_assignment(np.where(d <= match_radius, d, 1e9))
            dd = d[i, k][d[i, k] <= match_radius]
        for t in thresholds:
            row[f"within_{t:g}m"] = int((dd <= t).sum())
        rows.append(row)
    return pd.DataFrame(rows)


def read_colmap_tracks(path: str | Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """COLMAP ``points3D.bin`` -> (xyz (N, 3), per point the ids of the images observing it).

    Reads the binary format directly: the published scenes ship ``points3D.bin`` without
    ``images.bin``, which pycolmap needs to load a model.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "missing COLMAP points3D.bin")
    data = path.read_bytes()
    try:
        (n,), off = struct.unpack_from("<Q", data, 0), 8
        xyz, images = np.empty((n, 3)), []
        for i in range(n):
            _, x, y, z, _, _, _, _, length = struct.unpack_from("<QdddBBBdQ", data, off)
            off += 51
            track = np.frombuffer(data, dtype="<i4", count=2 * length, offset=off)
            off += 8 * length
            xyz[i] = (x, y, z)
            images.append(np.unique(track[0::2]))
    except (struct.error, ValueError) as exc:
        raise InputError(path, f"not a COLMAP points3D.bin ({exc})") from exc
    return xyz, images


def cluster_features(
    members: list[np.ndarray], points: np.ndarray, metres_per_unit: float, images: list[np.ndarray] | None = None
) -> pd.DataFrame:
    """What the cloud (and its SfM tracks, when given per point) knows about each cluster."""
    rows = []
    for idx in members:
        p = np.asarray(points, float)[idx]
        extent = float(np.ptp(p, axis=0).max() * metres_per_unit) if len(p) > 1 else 0.0
        row = {"points": len(idx), "extent_m": extent, "points_per_m": len(idx) / max(extent, 0.1)}
        if images is not None:
            seen = [images[i] for i in idx]
            row["images"] = len(np.unique(np.concatenate(seen))) if seen else 0
            row["track_median"] = float(np.median([len(s) for s in seen])) if seen else 0.0
        rows.append(row)
    return pd.DataFrame(rows)


def feature_auc(features: pd.DataFrame, kept: np.ndarray) -> dict[str, float]:
    """ROC AUC of each feature for telling kept clusters from dropped ones (0.5 = no information;
    far from 0.5 either way = a threshold on it would separate them)."""
    from sklearn.metrics import roc_auc_score

    kept = np.asarray(kept, bool)
    if kept.all() or not kept.any():
        return {c: float("nan") for c in features.columns}
    return {c: float(roc_auc_score(kept, features[c])) for c in features.columns}
