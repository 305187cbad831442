"""Localizing on a loaded map: one query (:func:`localize`), a sequence (:func:`localize_sequence`),
the files of ``flatlandia localize`` (:func:`localize_file`).

The pose is the map's (:meth:`~flatlandia.localize.object_map.ObjectMap.locate`):
:func:`flatlandia.solver.locate`'s on a scene map (the function rule fine_eval calls) and
:func:`flatlandia.city.search.search_city`'s on a city index; nothing here asks which kind a map is.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from flatlandia.localize.answers import answer_pose, answer_status, no_pose_reason, probability_of
from flatlandia.localize.gps_fixes import check_prior, fixes, gps_used, prior_warnings
from flatlandia.localize.maps import MAP_TYPES, load_map
from flatlandia.localize.object_map import ObjectMap
from flatlandia.localize.query_files import Query, Sequence, parse_query, parse_sequence, read_queries, read_sequence
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

#: next-best distinct poses returned by default (also `flatlandia localize --alternatives`'s default)
ALTERNATIVES = 3


#: a depth query whose median object range is within this of 1 is used as given: the benchmark's
#: depth maps are normalised so (the scale prior is in metres per such unit); any other is scaled
NORMALISED_TOL = 1e-4


def localize(
    m: ObjectMap,
    query: Query | dict,
    map_type: str = "gt",
    near: tuple[float, float] | None = None,
    radius_m: float | None = None,
    alternatives: int = ALTERNATIVES,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    rows: np.ndarray | None = None,
) -> dict:
    """One query's pose on a loaded map (:func:`load_map`), as a dict of JSON values.

    ``map_type``: ``gt`` (x/y in metres) or ``depth`` (any unit: the scale is solved for);
    ``near`` (lon, lat) and ``radius_m``: search only the map objects within ``radius_m`` of it (a
    prior position; on a city, in place of the index's regions). Keys: ``found``; the pose ``lon``,
    ``lat`` (None without a geographic frame), ``x_m``, ``y_m`` (the map's metric frame, ``frame``),
    ``heading_deg`` (compass: clockwise from north), ``theta_deg`` (the benchmark's: counter-clockwise
    from east), ``scale`` (metres per query unit; 1 for GT), ``confidence`` (share of the query's
    objects explained, lowered when a distinct pose is nearly as good), ``cost``, ``matches`` (query
    object -> ``obj_idx``, class, lon/lat), ``alternatives`` (the next-best distinct poses with their
    ``cost`` and ``behind``: how far the ranking puts them behind the best), ``priors`` (what the
    solver knew beyond the query and the map), ``searched`` (map objects searched) and ``seconds``
    (the solver's time); ``reason`` when nothing was found; ``status`` and ``probability``
    (:func:`answer_status`; each alternative has its ``probability``). ``gps`` (lon, lat, sigma_m) and
    ``compass`` (heading_deg clockwise from north, sigma_deg): a phone's fix, weighed as a likelihood
    (:func:`fixes`; not with ``near``). ``rows``: search only these rows of a scene map, in this order
    (a proposal: the objects a coarse stage, or the oracle box, proposes; as rule fine_eval does)."""
    if map_type not in MAP_TYPES:
        raise InputError("--map-type", f"{map_type!r} is not one of {', '.join(MAP_TYPES)}")
    q = query if isinstance(query, Query) else parse_query(query)
    if (near is None) != (radius_m is None):
        raise InputError("--near", "a prior position needs both near (lon, lat) and radius_m")
    if near is not None and not (
        math.isfinite(near[0]) and math.isfinite(near[1]) and abs(near[0]) <= 180 and abs(near[1]) <= 90
    ):
        raise InputError("--near", f"{near} is not lon, lat in degrees")
    if radius_m is not None and not (math.isfinite(radius_m) and 0 < radius_m <= validate.MAX_PRIOR_M):
        raise InputError("--radius-m", f"{radius_m} is not a positive number of metres up to {validate.MAX_PRIOR_M:g}")
    check_prior(gps, compass)
    if gps is not None and near is not None:
        raise InputError("--gps", "give either a GPS fix (--gps) or a search radius (--near), not both")
    if rows is not None and (not m.takes_rows or near is not None or gps is not None):
        raise InputError("--proposal", "a proposal (map rows) is searched on a scene map, without --near or --gps")
    xy, unit = _solver_units(q.xy, map_type)
    priors_used = m.priors_used(map_type)
    t0 = time.perf_counter()
    if gps is not None:
        best, alts, rows = _localize_with_fix(m, xy, q.cls, alternatives, fixes(m, gps, compass), map_type)
        priors_used["gps"] = gps_used(gps, compass)
    else:
        best, alts, rows = m.locate(xy, q.cls, map_type, alternatives, rows=rows, near=near, radius_m=radius_m)
    seconds = time.perf_counter() - t0
    if near is not None:
        priors_used["near"] = {"lon": float(near[0]), "lat": float(near[1]), "radius_m": float(radius_m)}
    out: dict[str, Any] = {"id": q.id, "map": str(m.path), "map_type": map_type, "found": best is not None}
    if best is None:
        out["reason"] = no_pose_reason(m, q.cls, rows, gps)
        pose = dict.fromkeys(("lon", "lat", "x_m", "y_m", "heading_deg", "theta_deg", "scale"))
        out.update(pose, confidence=0.0, cost=None, matches=[], alternatives=[])
    else:
        out.update(answer_pose(m, best, unit, rows, q), confidence=float(best.confidence), cost=float(best.cost))
        out["alternatives"] = [
            {
                **answer_pose(m, a, unit, rows, q),
                "cost": float(a.cost),
                "behind": float(a.behind),
                "probability": probability_of(a),
            }
            for a in alts
        ]
    out.update(answer_status(best, m.settings.answer_probability))
    out.update(frame=m.frame, priors=priors_used, searched=int(len(rows)), seconds=seconds)
    out["warnings"] = prior_warnings(m, gps=gps, near=near, radius_m=radius_m)
    return out


def _solver_units(xy: np.ndarray, map_type: str) -> tuple[np.ndarray, float]:
    """A local map in the solver's units and the unit: depth maps at a median object range of 1 (the
    scale prior's unit), GT maps as given."""
    if map_type == "depth":
        med = float(np.median(np.hypot(xy[:, 0], xy[:, 1])))
        if abs(med - 1.0) > NORMALISED_TOL:
            return xy / med, med
    return xy, 1.0


def _localize_with_fix(m: ObjectMap, xy, cls, alternatives: int, fx: list, map_type: str):
    """(best, alternatives, rows searched) of one query with a fix: the map searched within each
    fix's reach (on a city, one fix per tile the fix falls in), the fix as the solver's likelihood,
    the cheapest answer kept."""
    answers = [m.locate(xy, cls, map_type, alternatives, fix=fix) for fix in fx]
    found = [a for a in answers if a.best is not None]
    if not found:
        return None, [], answers[0].rows if answers else np.zeros(0, np.int64)
    return min(found, key=lambda a: a.best.cost)


def localize_sequence(
    m: ObjectMap,
    sequence: Sequence | dict,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    alternatives: int = ALTERNATIVES,
    settings=None,
) -> dict:
    """A sequence's anchor pose on a loaded map (depth local maps): :func:`flatlandia.solver.locate_sequence`
    on a scene map, :func:`flatlandia.city.search.search_city_sequence` on a city index, with the
    map's priors and an optional fix (``gps``, ``compass`` as :func:`localize`) of the anchor. The
    answer is :func:`localize`'s for the anchor (its ``matches`` are the anchor's objects'), plus
    ``frames``: every frame's pose (``id``, lon, lat, x_m, y_m, heading_deg, theta_deg, scale),
    anchor first. ``settings``: the sequence solver's (config section ``beyond.sequence``; None:
    the schema's defaults)."""
    from flatlandia import solver

    seq = sequence if isinstance(sequence, Sequence) else parse_sequence(sequence)
    check_prior(gps, compass)
    units = [_solver_units(f.xy, "depth") for f in seq.frames]
    frames = [(xy, f.cls) for (xy, _), f in zip(units, seq.frames)]
    priors_used = m.priors_used("depth")
    fx = fixes(m, gps, compass) if gps is not None else [None]
    t0 = time.perf_counter()
    answers = [m.locate_sequence(frames, seq.rel, seq.sigma, settings, alternatives, fix) for fix in fx]
    good = [a for a in answers if a[0].best is not None]
    if good:
        found, rows = min(good, key=lambda a: a[0].best.cost)
    else:  # no pose; a fix near no tile of a city gives no region to search
        found, rows = answers[0] if answers else (solver.SequenceLocalization(None), np.zeros(0, np.int64))
    seconds = time.perf_counter() - t0
    if gps is not None:
        priors_used["gps"] = gps_used(gps, compass)
    priors_used["sequence"] = {"frames": len(seq.frames)}
    anchor = seq.frames[0]
    out: dict[str, Any] = {"id": anchor.id, "map": str(m.path), "map_type": "depth", "found": found.best is not None}
    if found.best is None:
        out["reason"] = (
            no_pose_reason(m, None, rows, gps)
            if gps is not None
            else "no pose explains the sequence's objects on the map objects searched"
        )
        pose = dict.fromkeys(("lon", "lat", "x_m", "y_m", "heading_deg", "theta_deg", "scale"))
        out.update(pose, confidence=0.0, cost=None, matches=[], alternatives=[], frames=[])
    else:
        out.update(answer_pose(m, found.best, units[0][1], rows, anchor), confidence=float(found.best.confidence))
        out["cost"] = float(found.best.cost)
        out["alternatives"] = [
            {
                **answer_pose(m, a, units[0][1], rows, anchor),
                "cost": float(a.cost),
                "behind": float(a.behind),
                "probability": probability_of(a),
            }
            for a in found.alternatives
        ]
        out["frames"] = []
        for f, (p, (_, unit)) in enumerate(zip(found.frames, units)):
            theta = math.degrees(math.atan2(math.sin(p.theta), math.cos(p.theta)))
            lon, lat = m.lonlat_of(np.array([p.x, p.y]))
            out["frames"].append(
                {
                    "id": seq.frames[f].id,
                    "lon": lon,
                    "lat": lat,
                    "x_m": float(p.x),
                    "y_m": float(p.y),
                    "heading_deg": float((90.0 - theta) % 360.0) if lon is not None else None,
                    "theta_deg": float(theta),
                    "scale": float(p.scale) / unit,
                    **m.place(p.x, p.y),
                }
            )
    out.update(answer_status(found.best, m.settings.answer_probability))
    out.update(frame=m.frame, priors=priors_used, searched=int(len(rows)), seconds=seconds)
    out["warnings"] = prior_warnings(m, gps=gps)
    return out


def localize_file(
    map_path: str | Path | ObjectMap,
    query_path: str | Path | None,
    map_type: str | None = None,
    near: tuple[float, float] | None = None,
    radius_m: float | None = None,
    alternatives: int = ALTERNATIVES,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    sequence_path: str | Path | None = None,
    **load_args,
) -> dict:
    """``flatlandia localize``: the queries of a JSON file on a map file. One query in: its answer
    (:func:`localize`); a file of many: ``{"results": [answers]}``; a sequence file instead
    (``sequence_path``, depth maps): its anchor's answer with every frame's pose
    (:func:`localize_sequence`). ``gps``/``compass``: a fix of the query (of the sequence's anchor).
    The input is read and checked before the map loads (a bad query fails in a second).
    ``map_type`` None: ``depth`` for a sequence (the only type it takes), else ``gt``. ``map_path``
    may be a map already loaded (:func:`load_map`; ``--plot`` draws the answer on it)."""
    if map_type is None:
        map_type = "depth" if sequence_path is not None else "gt"
    if map_type not in MAP_TYPES:
        raise InputError("--map-type", f"{map_type!r} is not one of {', '.join(MAP_TYPES)}")
    check_prior(gps, compass)
    if (query_path is None) == (sequence_path is None):
        raise InputError("--query", "give a query file (--query) or a sequence file (--sequence), one of them")
    if sequence_path is not None:
        if map_type != "depth":
            raise InputError("--map-type", "a sequence is of depth local maps: --map-type depth")
        if near is not None:
            raise InputError("--near", "a sequence takes a GPS fix (--gps), not --near")
        seq = read_sequence(sequence_path)
        return localize_sequence(_loaded(map_path, load_args), seq, gps, compass, alternatives)
    queries, many = read_queries(query_path)
    m = _loaded(map_path, load_args)
    results = [localize(m, q, map_type, near, radius_m, alternatives, gps, compass) for q in queries]
    return {"results": results} if many else results[0]


def _loaded(map_path: str | Path | ObjectMap, load_args: dict) -> ObjectMap:
    """A map given loaded, or loaded from its file (:func:`load_map`)."""
    return map_path if isinstance(map_path, ObjectMap) else load_map(map_path, **load_args)
