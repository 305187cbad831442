"""One query against a city: the index proposes a few regions, the solver searches only those.

Why regions and not the whole map: the solver's hypotheses grow with the same-class candidate
pairs and triples of its map, so its time grows faster than the map, and every extra object is a
chance of a near-tie wrong answer. The index ranks the mapping views by the query's classes
(idf-weighted bag of classes, cosine), re-ranks the best ``top_views`` by how many query objects
one heading offset and one scale align with a view's objects, and keeps the ``regions`` best
distinct places (views at least ``nms_m`` apart). The solver then runs once on the objects within
``region_radius_m`` of those places, with the priors of the views there (its camera prior,
co-visibility and verifier read only views near a pose), so a query's cost grows slowly with the
city (validation split: 15 ms of CPU at 2,354 objects, 34 ms at 100,000, where the whole-map solver
takes 42 ms and, at 10,000 objects, 1.3 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from flatlandia import config, solver
from flatlandia.city import kernels
from flatlandia.city.index import ViewIndex


@config.settings("city.search")
class SearchConfig:
    """The search's settings: the config section ``city.search`` (each is described in
    config/README.md, ``city.search.*``)."""


def view_scores(ix: ViewIndex, q_xy: np.ndarray, q_cls: np.ndarray, cfg: SearchConfig) -> tuple[np.ndarray, np.ndarray]:
    """(views, scores) of the ``top_views`` best views, best first: bag-of-classes cosine in [0, 1]
    times ``bow_weight``, plus the aligned share of the query's class weight in [0, 1]."""
    q_cls = np.asarray(q_cls, np.int64)
    h = np.bincount(q_cls, minlength=len(ix.idf)).astype(float)
    q_mass = float(h @ ix.idf)
    common = ix.hist.copy()
    common.data = np.minimum(common.data, h[common.indices]) * ix.idf[common.indices]
    bow = np.asarray(common.sum(axis=1)).ravel() / np.sqrt(np.maximum(ix.view_mass * q_mass, 1e-12))
    top = np.argpartition(-bow, cfg.top_views - 1)[: cfg.top_views] if len(bow) > cfg.top_views else np.arange(len(bow))
    q = np.asarray(q_xy, float)
    agree = kernels.view_agreement(
        top.astype(np.int64),
        ix.view_ptr,
        ix.obj_cls[ix.view_obj],
        ix.view_bear,
        ix.view_logr,
        q_cls,
        np.arctan2(q[:, 1], q[:, 0]),
        np.log(np.hypot(q[:, 0], q[:, 1]) + 1e-9),
        ix.idf[q_cls],
        math.radians(cfg.bearing_tol_deg),
        float(cfg.log_range_tol),
    )
    score = agree / max(q_mass, 1e-12) + cfg.bow_weight * bow[top]
    order = np.argsort(-score, kind="stable")
    return top[order], score[order]


def region_centres(ix: ViewIndex, views: np.ndarray, cfg: SearchConfig) -> np.ndarray:
    """(K, 2) positions of the ``regions`` best views (in the given order) at least ``nms_m`` apart."""
    centres = np.zeros((0, 2))
    for v in views:
        p = ix.cam[v, :2]
        if len(centres) and np.min(np.hypot(*(centres - p).T)) < cfg.nms_m:
            continue
        centres = np.vstack([centres, p])
        if len(centres) == cfg.regions:
            break
    return centres


def _union(lists) -> np.ndarray:
    return np.unique(np.concatenate([np.asarray(x, np.int64) for x in lists] + [np.zeros(0, np.int64)]))


def region_priors(ix: ViewIndex, centres: np.ndarray, cfg: SearchConfig, prior_radius_m: float):
    """(map rows, view rows, seen (views, rows) booleans) of the regions: the objects within
    ``region_radius_m`` of a centre, the views within that plus ``prior_radius_m`` (a pose farther
    from every view is refused by the solver's gate), and which of the objects each view saw."""
    rows = _union(ix.obj_tree.query_ball_point(centres, cfg.region_radius_m)) if len(centres) else _union([])
    views = (
        _union(ix.cam_tree.query_ball_point(centres, cfg.region_radius_m + prior_radius_m))
        if len(centres) and ix.cam_tree is not None
        else _union([])
    )
    col = np.full(ix.n_objects, -1, np.int64)
    col[rows] = np.arange(len(rows))
    counts = ix.view_ptr[views + 1] - ix.view_ptr[views]
    which = np.repeat(np.arange(len(views)), counts)
    objs = np.concatenate([ix.seen(v) for v in views] + [np.zeros(0, np.int64)])
    seen = np.zeros((len(views), len(rows)), bool)
    inside = col[objs] >= 0
    seen[which[inside], col[objs[inside]]] = True
    return rows, views, seen


def region_training_priors(ix: ViewIndex, cams: np.ndarray, seen: np.ndarray, learned=None) -> solver.TrainingPriors:
    """The solver's priors on a search's regions: the training views near them and what they saw
    (:func:`region_priors`), the learned scale prior, and the verifier where there are views."""
    if not len(cams):
        return solver.TrainingPriors(scale=learned.scale if learned else None)
    return solver.TrainingPriors(ix.cam[cams], seen).with_learned(learned)


@dataclass
class Located:
    """A query's pose (None when the solver found none), the next-best distinct poses and what the
    index proposed."""

    solution: solver.Solution | None
    rows: np.ndarray  # map rows the solver searched
    centres: np.ndarray  # (K, 2) region centres, best first
    alternatives: list[solver.Solution] = field(default_factory=list)


def localize(
    ix: ViewIndex,
    q_xy,
    q_cls,
    cfg: SearchConfig,
    settings: solver.SolverConfig,
    learned: solver.LearnedPriors | None = None,
    metric: bool = False,
    alternatives: int = 0,
    centres: np.ndarray | None = None,
) -> Located:
    """Pose of a query in the city (a depth map; ``metric``: a GT map in metres): regions from the
    index (or the given ``centres``, (K, 2) metres, e.g. a user's prior position, with ``cfg``'s
    ``region_radius_m``), then the solver (:func:`flatlandia.solver.localize`, with up to
    ``alternatives`` next-best poses) on them with the training views near them as its priors
    (and for depth maps the ``learned`` scale prior and verifier)."""
    q_xy, q_cls = np.asarray(q_xy, float).reshape(-1, 2), np.asarray(q_cls, np.int64)
    if centres is None:
        views, _ = view_scores(ix, q_xy, q_cls, cfg)
        centres = region_centres(ix, views, cfg)
    rows, cams, seen = region_priors(ix, np.asarray(centres, float).reshape(-1, 2), cfg, settings.prior_radius_m)
    found = solver.Localization(None)
    if len(rows) >= 2:
        found = solver.localize(
            q_xy,
            q_cls,
            ix.obj_xy[rows],
            ix.obj_cls[rows],
            metric=metric,
            config=settings,
            priors=region_training_priors(ix, cams, seen, None if metric else learned),
            alternatives=alternatives,
        )
    return Located(found.best, rows, centres, found.alternatives)
