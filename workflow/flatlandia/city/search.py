"""One query against a city: the index proposes a few regions, the solver searches only those.

Why regions and not the whole map: the solver's hypotheses grow with the same-class candidate
pairs and triples of its map, so its time grows faster than the map, and every extra object is a
chance of a near-tie wrong answer. The index ranks the mapping views by the query's classes
(idf-weighted bag of classes, cosine), re-ranks the best ``top_views`` by how many query objects
one heading offset and one scale align with a view's objects, and keeps the ``regions`` best
distinct places (views at least ``nms_m`` apart). The solver then runs once on the objects within
``region_radius_m`` of those places, with the priors of the views there (its camera prior,
co-visibility and verifier read only views near a pose), so a query's cost grows slowly with the
city, where the whole-map solver's grows faster than the map (measured: docs/measurements.md, "City search").

The index ranked every place of the city, so an answer's probability is lowered by the cities'
map-size correction (:class:`flatlandia.solver.calibration.MapSize`, in ``learned``'s calibration:
rule city_calibration) for the index's objects; a search on given places (a fix's region, a prior
position) is not.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from flatlandia import config, solver
from flatlandia.city import view_kernels
from flatlandia.city.index import ViewIndex
from flatlandia.solver import regions


@config.settings("city.search")
class SearchConfig:
    """The search's settings: the config section ``city.search`` (each is described in
    config/README.md, ``city.search.*``)."""


def view_scores(
    ix: ViewIndex, q_xy: np.ndarray, q_cls: np.ndarray, cfg: SearchConfig, exclude: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(views, scores) of the ``top_views`` best views, best first: bag-of-classes cosine in [0, 1]
    times ``bow_weight``, plus the aligned share of the query's class weight in [0, 1]. Views in
    ``exclude`` (rows of the index's views, e.g. a sequence's companions) are never ranked."""
    q_cls = np.asarray(q_cls, np.int64)
    h = np.bincount(q_cls, minlength=len(ix.idf)).astype(float)
    q_mass = float(h @ ix.idf)
    common = ix.hist.copy()
    common.data = np.minimum(common.data, h[common.indices]) * ix.idf[common.indices]
    bow = np.asarray(common.sum(axis=1)).ravel() / np.sqrt(np.maximum(ix.view_mass * q_mass, 1e-12))
    if exclude is not None and len(exclude):
        bow[np.asarray(exclude, np.int64)] = -np.inf
    top = np.argpartition(-bow, cfg.top_views - 1)[: cfg.top_views] if len(bow) > cfg.top_views else np.arange(len(bow))
    top = top[np.isfinite(bow[top])]
    q = np.asarray(q_xy, float)
    agree = view_kernels.view_agreement(
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


def region_centres(ix: ViewIndex, views: np.ndarray, cfg: SearchConfig, regions: int | None = None) -> np.ndarray:
    """(K, 2) positions of the ``regions`` (default ``cfg.regions``) best views (in the given order)
    at least ``nms_m`` apart."""
    regions = int(cfg.regions if regions is None else regions)
    centres = np.zeros((0, 2))
    for v in views:
        p = ix.cam[v, :2]
        if len(centres) and np.min(np.hypot(*(centres - p).T)) < cfg.nms_m:
            continue
        centres = np.vstack([centres, p])
        if len(centres) == regions:
            break
    return centres


def _union(lists) -> np.ndarray:
    return np.unique(np.concatenate([np.asarray(x, np.int64) for x in lists] + [np.zeros(0, np.int64)]))


def region_priors(
    ix: ViewIndex,
    centres: np.ndarray,
    cfg: SearchConfig,
    prior_radius_m: float,
    exclude: np.ndarray | None = None,
    radius_m: float | None = None,
):
    """(map rows, view rows, seen (views, rows) booleans) of the regions: the objects within
    ``radius_m`` (default ``region_radius_m``) of a centre, the views within that plus
    ``prior_radius_m`` (a pose farther from every view is refused by the solver's gate) except those
    in ``exclude``, and which of the objects each view saw."""
    radius = float(cfg.region_radius_m if radius_m is None else radius_m)
    rows = _union(ix.obj_tree.query_ball_point(centres, radius)) if len(centres) else _union([])
    views = (
        _union(ix.cam_tree.query_ball_point(centres, radius + prior_radius_m))
        if len(centres) and ix.cam_tree is not None
        else _union([])
    )
    if exclude is not None and len(exclude):
        views = views[~np.isin(views, np.asarray(exclude, np.int64))]
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
        return solver.with_learned(solver.TrainingPriors(), learned)
    return solver.with_learned(solver.TrainingPriors(ix.cam[cams], seen), learned)


def in_city(solutions: list, learned, ix: ViewIndex, frames: int = 1) -> list:
    """``solutions`` (None kept) with their probability lowered for the ``ix.n_objects`` objects the
    index ranked (the map-size correction of ``learned``'s calibration; as they are without one)."""
    cal = learned.calibration if learned is not None else None
    if cal is None or cal.map_size is None:
        return list(solutions)
    return [
        s
        if s is None
        else dataclasses.replace(s, probability=float(cal.in_map([s.probability], ix.n_objects, frames)[0]))
        for s in solutions
    ]


@dataclass
class Located:
    """A query's pose (None when the solver found none), the next-best distinct poses and what the
    index proposed."""

    solution: solver.Solution | None
    rows: np.ndarray  # map rows the solver searched
    centres: np.ndarray  # (K, 2) region centres, best first
    alternatives: list[solver.Solution] = field(default_factory=list)


def search_city(
    ix: ViewIndex,
    q_xy,
    q_cls,
    cfg: SearchConfig,
    settings: solver.SolverConfig,
    learned: solver.LearnedPriors | None = None,
    metric: bool = False,
    alternatives: int = 0,
    centres: np.ndarray | None = None,
    fix: solver.Fix | None = None,
    exclude: np.ndarray | None = None,
) -> Located:
    """Pose of a query in the city (a depth map; ``metric``: a GT map in metres): regions from the
    index (or the given ``centres``, (K, 2) metres, e.g. a user's prior position, with ``cfg``'s
    ``region_radius_m``), then the solver (:func:`flatlandia.solver.locate`, with up to
    ``alternatives`` next-best poses) on them with the training views near them as its priors
    (and for depth maps the ``learned`` scale prior and verifier). With a ``fix`` (GPS) and no
    ``centres``, the one region is the fix's (objects within ``Fix.crop_m``) and the fix is the
    solver's likelihood too. ``exclude``: views (rows of the index's) neither ranked nor used as
    priors (a sequence's companions)."""
    q_xy, q_cls = np.asarray(q_xy, float).reshape(-1, 2), np.asarray(q_cls, np.int64)
    radius, ranked = None, centres is None and fix is None
    if centres is None and fix is not None:
        centres, radius = fix.xy[None], fix.crop_m
    elif centres is None:
        views, _ = view_scores(ix, q_xy, q_cls, cfg, exclude)
        centres = region_centres(ix, views, cfg)
    centres = np.asarray(centres, float).reshape(-1, 2)
    if ranked and cfg.by_region and len(centres) > 1:
        return _by_region(ix, q_xy, q_cls, centres, cfg, settings, learned, metric, alternatives, exclude)
    rows, cams, seen = region_priors(ix, centres, cfg, settings.prior_radius_m, exclude, radius)
    found = solver.Localization(None)
    if len(rows) >= 2:
        found = _locate_rows(ix, q_xy, q_cls, rows, cams, seen, settings, learned, metric, alternatives, fix)
    best, alts = found.best, found.alternatives
    if ranked and not metric:
        best, *alts = in_city([best, *alts], learned, ix)
    return Located(best, rows, centres, alts)


def _by_region(ix, q_xy, q_cls, centres, cfg, settings, learned, metric, alternatives, exclude) -> Located:
    """:func:`search_city` on each of the index's regions alone, the answers combined by their
    share of the regions' evidence (:func:`flatlandia.solver.regions.combine`), then the map-size
    correction."""
    found, union = _each_region(
        ix,
        centres,
        cfg,
        settings,
        exclude,
        lambda rows, cams, seen: _locate_rows(
            ix, q_xy, q_cls, rows, cams, seen, settings, learned, metric, max(alternatives, 2)
        ),
    )
    cal = learned.calibration if learned is not None and not metric else None
    best, alts, _ = regions.combine(found, cal, len(q_cls), 1, alternatives)
    if not metric:
        best, *alts = in_city([best, *alts], learned, ix)
    return Located(best, union, centres, alts)


def _locate_rows(ix, q_xy, q_cls, rows, cams, seen, settings, learned, metric, alternatives, fix=None):
    """:func:`flatlandia.solver.locate` on the index's map ``rows`` with the views ``cams`` (what
    they saw: ``seen``) as priors, and for depth maps the ``learned`` ones."""
    return solver.locate(
        q_xy,
        q_cls,
        ix.obj_xy[rows],
        ix.obj_cls[rows],
        metric=metric,
        config=settings,
        priors=region_training_priors(ix, cams, seen, None if metric else learned),
        alternatives=alternatives,
        fix=fix,
    )


def _locate_sequence_rows(
    ix, frames, rel_poses, rows, cams, seen, settings, seq, learned, odometry_sigma, fix, alternatives
):
    """:func:`flatlandia.solver.locate_sequence` on the index's map ``rows`` with the views ``cams``
    (what they saw: ``seen``) and the ``learned`` priors."""
    return solver.locate_sequence(
        frames,
        rel_poses,
        ix.obj_xy[rows],
        ix.obj_cls[rows],
        settings,
        region_training_priors(ix, cams, seen, learned),
        seq,
        odometry_sigma,
        fix,
        alternatives,
    )


def _each_region(ix, centres, cfg, settings, exclude, solve):
    """(answers, searched rows) of ``solve(rows, cams, seen)`` on each region of ``centres`` alone
    (those with two objects at least), each answer's inliers indexed into the sorted union of the
    rows every region searched (:func:`_in_union`)."""
    found, searched = [], []
    for c in centres:
        rows, cams, seen = region_priors(ix, c[None], cfg, settings.prior_radius_m, exclude)
        if len(rows) < 2:
            continue
        searched.append(rows)
        found.append(solve(rows, cams, seen))
    union = _union(searched)
    return [_in_union(loc, rows, union) for loc, rows in zip(found, searched)], union


def _in_union(loc, rows: np.ndarray, union: np.ndarray):
    """``loc`` (solved on a region's ``rows``) with its inliers' candidate indices into ``union``
    (the rows every region searched, sorted), as :class:`Located` holds them."""

    def moved(s):
        if s is None:
            return s
        at = np.searchsorted(union, rows[[c for _, c in s.inliers]]) if s.inliers else []
        return dataclasses.replace(s, inliers=[(q, int(a)) for (q, _), a in zip(s.inliers, at)])

    return dataclasses.replace(loc, best=moved(loc.best), alternatives=[moved(s) for s in loc.alternatives])


def sequence_centres(ix: ViewIndex, frames, cfg: SearchConfig, exclude: np.ndarray | None = None) -> np.ndarray:
    """(K, 2) region centres of a sequence: every frame ranks the views (:func:`view_scores`), a
    view's score is the sum over the frames that ranked it (the frames stand metres apart, so the
    right place's views gather every frame's vote), and the ``sequence_regions`` best distinct
    places follow (:func:`region_centres`)."""
    total: dict[int, float] = {}
    for xy, cls in frames:
        views, scores = view_scores(ix, np.asarray(xy, float).reshape(-1, 2), np.asarray(cls, np.int64), cfg, exclude)
        for v, sc in zip(views.tolist(), scores.tolist()):
            total[v] = total.get(v, 0.0) + sc
    if not total:
        return np.zeros((0, 2))
    views = np.array(list(total), np.int64)
    score = np.array([total[v] for v in views.tolist()])
    return region_centres(ix, views[np.argsort(-score, kind="stable")], cfg, cfg.sequence_regions)


def search_city_sequence(
    ix: ViewIndex,
    frames,
    rel_poses,
    cfg: SearchConfig,
    settings: solver.SolverConfig,
    sequence_settings=None,
    learned: solver.LearnedPriors | None = None,
    odometry_sigma=None,
    fix: solver.Fix | None = None,
    exclude: np.ndarray | None = None,
    alternatives: int = 0,
) -> tuple[solver.SequenceLocalization, Located]:
    """A sequence of depth frames (anchor first; :func:`flatlandia.solver.locate_sequence`'s
    arguments) in the city: the regions of the frames' summed view ranking (:func:`sequence_centres`)
    or, with a ``fix``, the fix's region; then the sequence solver on their objects with the views
    there as priors (``exclude``: views neither ranked nor used, e.g. the companions'). One frame is
    :func:`search_city`. Returns (the sequence's answer, the search's regions)."""
    frames = list(frames)
    if len(frames) == 1:
        found = search_city(ix, *frames[0], cfg, settings, learned, False, alternatives, fix=fix, exclude=exclude)
        b = found.solution
        poses = [solver.sequence.FramePose(b.x, b.y, b.theta, b.scale)] if b is not None else []
        return solver.SequenceLocalization(b, found.alternatives, poses), found
    radius = None
    if fix is not None:
        centres, radius = fix.xy[None], fix.crop_m
    else:
        centres = sequence_centres(ix, frames, cfg, exclude)
    if fix is None and cfg.sequence_by_region and len(centres) > 1:
        return _sequence_by_region(
            ix,
            frames,
            rel_poses,
            centres,
            cfg,
            settings,
            sequence_settings,
            learned,
            odometry_sigma,
            exclude,
            alternatives,
        )
    rows, cams, seen = region_priors(ix, centres, cfg, settings.prior_radius_m, exclude, radius)
    located = Located(None, rows, centres)
    if len(rows) < 2:
        return solver.SequenceLocalization(None), located
    found = _locate_sequence_rows(
        ix, frames, rel_poses, rows, cams, seen, settings, sequence_settings, learned, odometry_sigma, fix, alternatives
    )
    if fix is None:
        best, *alts = in_city([found.best, *found.alternatives], learned, ix, len(frames))
        found = dataclasses.replace(found, best=best, alternatives=alts)
    located.solution, located.alternatives = found.best, found.alternatives
    return found, located


def _sequence_by_region(
    ix, frames, rel_poses, centres, cfg, settings, sequence_settings, learned, odometry_sigma, exclude, alternatives
):
    """:func:`search_city_sequence` on each region alone, combined as :func:`_by_region` does."""
    found, union = _each_region(
        ix,
        centres,
        cfg,
        settings,
        exclude,
        lambda rows, cams, seen: _locate_sequence_rows(
            ix,
            frames,
            rel_poses,
            rows,
            cams,
            seen,
            settings,
            sequence_settings,
            learned,
            odometry_sigma,
            None,
            max(alternatives, 2),
        ),
    )
    cal = learned.calibration if learned is not None else None
    best, alts, winner = regions.combine(found, cal, len(frames[0][1]), len(frames), alternatives)
    best, *alts = in_city([best, *alts], learned, ix, len(frames))
    answer = solver.SequenceLocalization(best, alts, found[winner].frames if winner >= 0 else [])
    return answer, Located(best, union, centres, alts)
