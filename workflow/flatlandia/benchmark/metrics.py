"""The benchmark's measures, one room for every stage that scores poses: the thresholds (the paper's,
the field's recalls, within (5 m, 5 deg)), one query's row of errors (:func:`error_row`), the
summary of a table of them (:func:`summarise`) and the answers' figures (:func:`answer_summary`).

Why a room of its own: the fine stage, the city search, the sequences and ``flatlandia score`` all
write rows and summaries that must read alike; each imports them from here (below every one of
them) rather than from the fine stage. Errors are true metres (scene metric frame) and degrees;
the paper reports local-map units x 215 as "metres" (docs/conventions.md, "The paper's metres"),
which ``error_paper_m`` gives beside them.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pandas as pd

from flatlandia import geo, paper

#: errors above this many metres count as gross
GROSS_M = 30.0
#: summary keys of the % of queries under each of the paper's thresholds: in true metres and in
#: the paper's convention (local-map units x 215)
THRESHOLD_COLUMNS = [f"pct_{m:g}m_{d:g}deg" for m, d in paper.THRESHOLDS]
PAPER_UNIT_THRESHOLD_COLUMNS = [f"pct_pu_{m:g}m_{d:g}deg" for m, d in paper.THRESHOLDS]
#: the field's recall thresholds (visual localization, e.g. OrienterNet): position and heading
#: apart, true metres and degrees, so that our rows read against the field's published figures
RECALL_M = (1.0, 3.0, 5.0)
RECALL_DEG = (1.0, 3.0, 5.0)
#: summary keys of the % of queries under each recall threshold: positions, then headings
RECALL_COLUMNS = [f"recall_{m:g}m" for m in RECALL_M] + [f"recall_{d:g}deg" for d in RECALL_DEG]
#: position and heading at once: the share of queries a user would call localized (the README's
#: headline figure)
WITHIN = (5.0, 5.0)
WITHIN_COLUMN = "within_5m_5deg"
#: a pose farther than this from the truth is in the wrong scene (a city's tiles lie 1 km apart;
#: scenes are < 300 m across); on a scene map no pose is
WRONG_SCENE_M = 500.0
#: summary keys of the answers' probability (:func:`answer_summary`)
ANSWER_COLUMNS = [
    "answered_pct",
    "within_answered_pct",
    "wrong_scene_answered_pct",
    "answerable_95_pct",
    "answerable_wrong_1pct",
    "answerable_wrong_2pct",
    "ece_points",
]


def solvable(query_classes, proposal_classes, min_objects: int = geo.MIN_OBJECTS) -> bool:
    """Can the proposal hold a solution: at least ``min_objects`` objects of the query's classes.

    Counted as a multiset match: each query object can use one proposal object of its class.
    """
    need = pd.Series(list(query_classes)).value_counts()
    have = pd.Series(list(proposal_classes)).value_counts()
    usable = sum(min(int(n), int(have.get(c, 0))) for c, n in need.items())
    return usable >= min_objects


# ----------------------------------------------------------------------------- errors


@functools.lru_cache(maxsize=256)
def metres_per_unit(lat: float) -> float:
    """Mean true metres per published local-map unit (tf/2 degrees) at a latitude (cached: a
    projection is built per call, dear beside a query, and evaluation asks once per query; docs/measurements.md,
    "Start-up costs")."""
    mx, my = geo.MetricFrame(0.0, float(lat)).metres_per_degree()
    return geo.UNIT_DEG * (mx + my) / 2


def paper_metres(error_m, lat: float):
    """A true-metre error in the paper's convention (local-map units x 215)."""
    return np.asarray(error_m, float) / metres_per_unit(lat) * paper.METRES_PER_UNIT


def summarise(errors: pd.DataFrame) -> dict:
    """Median errors, % under the paper's thresholds, the field's recalls (position and heading
    apart), F%, gross share, mean/median query time, the answers' figures (:func:`answer_summary`).

    Failed queries (no pose) count with infinite error and a 180 deg heading: misses at every
    threshold. ``F%`` is the share of queries whose proposal cannot hold a solution (fewer than 3
    objects of the query's classes).
    """
    e = errors
    em = e["error_m"].to_numpy(float)
    ed = e["error_deg"].to_numpy(float)
    out = {
        "queries": int(len(e)),
        "median_m": float(np.median(em)) if len(e) else float("nan"),
        "median_deg": float(np.median(ed)) if len(e) else float("nan"),
    }
    for column, (m, d) in zip(THRESHOLD_COLUMNS, paper.THRESHOLDS):
        out[column] = float(100 * np.mean((em < m) & (ed < d))) if len(e) else float("nan")
    for column, (err, t) in zip(RECALL_COLUMNS, [(em, m) for m in RECALL_M] + [(ed, d) for d in RECALL_DEG]):
        out[column] = float(100 * np.mean(err < t)) if len(e) else float("nan")
    out[WITHIN_COLUMN] = float(100 * np.mean((em < WITHIN[0]) & (ed < WITHIN[1]))) if len(e) else float("nan")
    out["failure_pct"] = float(100 * np.mean(~e["solvable"].to_numpy(bool))) if len(e) else float("nan")
    out["no_pose_pct"] = float(100 * np.mean(~np.isfinite(em))) if len(e) else float("nan")
    out["gross_pct"] = float(100 * np.mean(em > GROSS_M)) if len(e) else float("nan")
    out["mean_query_s"] = float(e["seconds"].mean()) if len(e) else float("nan")
    out["median_query_s"] = float(e["seconds"].median()) if len(e) else float("nan")
    if "cpu_seconds" in e:  # CPU time of the process: robust to other load on a shared machine
        out["median_query_cpu_s"] = float(e["cpu_seconds"].median()) if len(e) else float("nan")
    out.update(answer_summary(e))
    if "error_paper_m" in e:  # the paper's convention: local-map units x 215, same thresholds
        pu = e["error_paper_m"].to_numpy(float)
        out["median_pu"] = float(np.median(pu)) if len(e) else float("nan")
        for column, (m, d) in zip(PAPER_UNIT_THRESHOLD_COLUMNS, paper.THRESHOLDS):
            out[column] = float(100 * np.mean((pu < m) & (ed < d))) if len(e) else float("nan")
    return out


def answer_summary(errors: pd.DataFrame) -> dict:
    """The answers' figures (:data:`ANSWER_COLUMNS`) of rows with ``probability`` (P(within (5 m, 5
    deg)), NaN: a method without one) and ``answered`` (status ok at the config's threshold): % answered,
    % within (5 m, 5 deg) and % in the wrong scene among the answered, the largest share answerable
    (by decreasing probability) with at least 95 % of the answered within and with at most 1 % and 2 %
    in the wrong scene, and the expected calibration error (10 bins, points). NaN where undefined
    (no probability, nothing answered)."""
    from flatlandia.solver import calibration

    nan = float("nan")
    out = dict.fromkeys(ANSWER_COLUMNS, nan)
    if not len(errors):
        return out
    em, ed = errors["error_m"].to_numpy(float), errors["error_deg"].to_numpy(float)
    within = (em < WITHIN[0]) & (ed < WITHIN[1])
    wrong = np.isfinite(em) & (em > WRONG_SCENE_M)
    answered = errors["answered"].to_numpy(bool) if "answered" in errors else np.ones(len(errors), bool)
    out["answered_pct"] = float(100 * answered.mean())
    if answered.any():
        out["within_answered_pct"] = float(100 * within[answered].mean())
        out["wrong_scene_answered_pct"] = float(100 * wrong[answered].mean())
    prob = errors["probability"].to_numpy(float) if "probability" in errors else np.full(len(errors), nan)
    if np.isfinite(prob).all():
        out["answerable_95_pct"] = calibration.largest_coverage(prob, ~within, 5.0)
        out["answerable_wrong_1pct"] = calibration.largest_coverage(prob, wrong, 1.0)
        out["answerable_wrong_2pct"] = calibration.largest_coverage(prob, wrong, 2.0)
        out["ece_points"] = calibration.expected_calibration_error(prob, within)
    return out


def ref_map_kb(ref: pd.DataFrame) -> float:
    """Size of a reference map as the methods read it: 2 x float32 + a class byte per object, kB."""
    return 9 * len(ref) / 1000


def answered(sol, cfg) -> bool:
    """A pose whose probability is at least ``solver.answer_probability`` (status ok); a pose
    without a probability (NaN) is answered."""
    if sol is None:
        return False
    return bool(not np.isfinite(sol.probability) or sol.probability >= cfg.answer_probability)


def error_row(
    query,
    method: str,
    map_type: str,
    strategy: str,
    proposal_classes: np.ndarray,
    lat: float,
    pose: tuple,
    errors: tuple,
    fit: tuple,
    seconds: float,
    cpu_seconds: float,
    matches: list[int] | None = None,
    probability: float = float("nan"),
    answered: bool = True,
) -> dict:
    """One query's row of an errors table. Why one function: the solver's and the learned models'
    rows must share their columns, which fine_table reads alike.

    ``query``: the query row; ``pose``: (x, y, heading in radians), NaN without a pose;
    ``errors``: (metres, degrees); ``fit``: the solver's (confidence, inliers, correct inliers);
    ``matches``: the solver's reference ``obj_idx`` per local-map object (-1: unmatched), for the
    figures and the viewer; empty for learned models, which match nothing; ``probability``: the
    solver's P(within (5 m, 5 deg)) (NaN: a method without one) and ``answered``: its status is ok
    at the config's threshold (``solver.answer_probability``; methods without a probability answer
    every query they place).
    """
    x, y, theta = pose
    error_m, error_deg = errors
    confidence, n_inliers, n_correct_inliers = fit
    return {
        "scene": str(query.scene),
        "token": str(query.token),
        "method": method,
        "map_type": map_type,
        "strategy": strategy,
        "n_objects": int(query.n_objects),
        "proposal_size": int(len(proposal_classes)),
        "solvable": bool(solvable(query.classes, proposal_classes)) if len(proposal_classes) else False,
        "x": float(x),
        "y": float(y),
        "theta_deg": math.degrees(theta) if np.isfinite(theta) else float("nan"),
        "error_m": float(error_m),
        "error_deg": float(error_deg),
        "error_paper_m": float(paper_metres(error_m, lat)),
        "confidence": float(confidence),
        "n_inliers": int(n_inliers),
        "n_correct_inliers": int(n_correct_inliers),
        "seconds": float(seconds),
        "cpu_seconds": float(cpu_seconds),
        "matched_obj_idx": [int(m) for m in (matches or [])],
        "probability": float(probability),
        "answered": bool(answered),
    }
