"""Graphs of the coarse localization task (the paper's "Coarse map localization").

* **Reference graph** (one per scene): one node per reference object; each node receives
  directed edges from its ``k = 7`` nearest neighbours (messages flow neighbour -> node).
* **Query graph** (one per query and local-map type): one node per query object, fully
  connected (no self loops; the GAT layer adds them).
* **Node features** ``[one-hot class (42), x, y]``; **edge feature** ``exp(-d)`` with ``d`` the
  distance between the two nodes in the same normalised units as ``x, y``.

Normalisation (one rule for every graph, so distances and edge features are comparable):

* reference maps: metres of the scene metric frame, centred on the mean of the scene's
  objects, divided by ``scale_m`` (default 50 m: scenes span 70-250 m, so ``x, y`` lie in
  about [-3, 3] and a 7-NN edge of ~10 m has ``exp(-d)`` about 0.8);
* GT local maps: metres in the camera frame, centred on the mean of the query's objects
  (the camera position is unknown to the model at test time anyway), divided by ``scale_m``;
* depth local maps: published with an unknown per-query scale and stored normalised so the
  median object range is 1 (``localmaps.normalise_depth_map``). They are multiplied by one
  fixed ``depth_unit_m`` (the median object range of the *training* GT maps, about 27 m,
  computed by :func:`median_range_m` and saved in the model config), then treated as metres
  like a GT map. The per-query oracle scale is never used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch

from flatlandia import config
from flatlandia.classes import N_CLASSES
from flatlandia.data import localmaps
from flatlandia.plumbing.pyg import Batch, Data

#: Defaults: the `coarse.train` section of workflow/schemas/config.schema.yaml.
_TRAIN = config.section_defaults("coarse.train")
#: neighbours per reference node (the default of `coarse.train.knn`)
REF_KNN = _TRAIN["knn"]
#: metres assumed for one unit of a normalised depth map when no training median is given
#: (`coarse.train.depth_unit_m` null and no training maps measured: about their median object range)
DEPTH_UNIT_M = 27.0


@dataclass(frozen=True)
class GraphConfig:
    scale_m: float = _TRAIN["scale_m"]  # metres per normalised unit
    depth_unit_m: float = DEPTH_UNIT_M  # metres assumed for one unit of a normalised depth map
    knn: int = REF_KNN  # reference graph: in-edges from the k nearest neighbours
    n_classes: int = N_CLASSES


def one_hot(classes, n_classes: int = N_CLASSES) -> np.ndarray:
    classes = np.asarray(classes, int)
    if classes.size and (classes.min() < 0 or classes.max() >= n_classes):
        raise ValueError(f"class ids outside 0..{n_classes - 1}: {sorted(set(classes.tolist()))}")
    out = np.zeros((len(classes), n_classes), np.float32)
    out[np.arange(len(classes)), classes] = 1.0
    return out


def knn_edges(xy: np.ndarray, k: int = REF_KNN) -> np.ndarray:
    """(2, E) edges ``j -> i`` for the ``k`` nearest neighbours ``j`` of every node ``i``.

    Ties are broken by index (stable sort), so the graph is deterministic. With fewer than
    ``k + 1`` nodes every node is connected to all the others.
    """
    xy = np.asarray(xy, float)
    n = len(xy)
    if n < 2:
        return np.zeros((2, 0), np.int64)
    k = min(k, n - 1)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    nbr = np.argsort(d, axis=1, kind="stable")[:, :k]  # (n, k)
    dst = np.repeat(np.arange(n), k)
    return np.stack([nbr.reshape(-1), dst]).astype(np.int64)


def full_edges(n: int) -> np.ndarray:
    """(2, n(n-1)) edges of the complete directed graph without self loops."""
    src, dst = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    keep = src != dst
    return np.stack([src[keep], dst[keep]]).astype(np.int64)


def _graph(xy_norm: np.ndarray, classes, edges: np.ndarray, cfg: GraphConfig, **extra) -> Data:
    xy_norm = np.asarray(xy_norm, np.float32).reshape(-1, 2)
    x = np.concatenate([one_hot(classes, cfg.n_classes), xy_norm], axis=1)
    dist = np.linalg.norm(xy_norm[edges[0]] - xy_norm[edges[1]], axis=1) if edges.size else np.zeros(0)
    return Data(
        x=torch.from_numpy(x),
        edge_index=torch.from_numpy(edges),
        edge_attr=torch.from_numpy(np.exp(-dist).astype(np.float32)[:, None]),
        pos=torch.from_numpy(xy_norm),
        **extra,
    )


def reference_graph(ref: pd.DataFrame, cfg: GraphConfig = GraphConfig()) -> Data:
    """The kNN graph of a scene's reference map (rows in ``ref`` order; ``obj_idx`` kept)."""
    xy = ref[["x_m", "y_m"]].to_numpy(float)
    xy_norm = (xy - xy.mean(0)) / cfg.scale_m
    return _graph(
        xy_norm,
        ref["class_id"].to_numpy(),
        knn_edges(xy, cfg.knn),
        cfg,
        obj_idx=torch.tensor(ref["obj_idx"].to_numpy(np.int64)),
    )


def local_map_metres(row, map_type: str, cfg: GraphConfig = GraphConfig()) -> np.ndarray:
    """A query's local map in (assumed) metres: GT as is, depth x ``cfg.depth_unit_m``."""
    local = localmaps.local_map(row, map_type)
    return local * cfg.depth_unit_m if map_type == "depth" else local


def query_graph(local_xy_m: np.ndarray, classes, cfg: GraphConfig = GraphConfig()) -> Data:
    """The fully connected graph of a query local map given in metres (camera frame)."""
    xy = np.asarray(local_xy_m, float).reshape(-1, 2)
    if len(xy) != len(classes):
        raise ValueError(f"local map has {len(xy)} objects but {len(classes)} classes")
    return _graph((xy - xy.mean(0)) / cfg.scale_m, classes, full_edges(len(xy)), cfg)


def median_range_m(queries: pd.DataFrame) -> float:
    """Median over queries of the median object range of their GT local maps (metres)."""
    med = [np.median(np.linalg.norm(localmaps.xy(c), axis=1)) for c in queries["gt_local_xy_m"]]
    return float(np.median(med))


def batch(graphs: list[Data]) -> Batch:
    """A torch-geometric batch (node offsets applied to ``edge_index``, ``batch`` vector set)."""
    return Batch.from_data_list(graphs)
