"""Fine 3DoF localization, rule fine_eval: per-query errors of the geometric solver and of the
learned models, and their summary.

Errors are true metres (scene metric frame) and degrees. The paper reports local-map units x 215
as "metres" (docs/conventions.md, "The paper's metres"); ``error_paper_m`` gives that convention
so that rows can be read against its Tables 4 and 5, but our headline figures are true metres.
Proposals come as tables of :mod:`flatlandia.proposals`.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from flatlandia import geo, paper, solver
from flatlandia import proposals as proposals_module
from flatlandia.data import localmaps
from flatlandia.geo import pose_errors  # noqa: F401 - the errors of this module's tables, for its readers

# torch and torch-geometric load slowly (docs/measurements.md, "Start-up costs"): only the learned
# models' evaluation needs them
if TYPE_CHECKING:
    from torch import nn

    from flatlandia.fine import models

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


def json_safe(d: dict) -> dict:
    """Non-finite floats as None (JSON has no inf/NaN)."""
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


# ----------------------------------------------------------------------------- solver evaluation


def solver_errors(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    map_type: str,
    proposal: str,
    settings: dict | None,
    learned: solver.LearnedPriors | None = None,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    split: str = "test",
    every: int = 1,
    progress: Callable[[str], Callable] | None = None,
) -> pd.DataFrame:
    """The fine stage's solver runs, as rule fine_eval and ``benchmarks/bench_fine_solver.py`` run
    them: per-query errors of the ``split`` queries (every ``every``-th) of each scene (reference
    map, queries) on their ``proposal`` (:func:`flatlandia.proposals.for_queries`), with the
    scene's training priors and, for depth maps, the ``learned`` scale prior and verifier.
    ``progress(scene)`` gives a progress wrapper per scene."""
    parts = []
    for ref, q in scenes:
        test = q[q["split"] == split].iloc[::every]
        props = proposals_module.for_queries(ref, test, proposal, map_type, coarse, strategy)
        scene = str(ref["scene"].iloc[0]) if len(ref) else ""
        parts.append(
            evaluate_solver(
                ref,
                test,
                props,
                map_type,
                settings,
                priors=solver.scene_priors(ref, q, settings, learned if map_type == "depth" else None),
                method="geometric solver",
                progress=progress(f"scene {scene}") if progress else None,
            )
        )
    return pd.concat(parts, ignore_index=True)


def model_errors(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    model: nn.Module,
    cfg: models.FineTrainConfig,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    crop_m: float = 0.0,
    split: str = "test",
) -> pd.DataFrame:
    """The fine stage's runs of a learned model, as rule fine_eval runs them: per-query errors of
    the ``split`` queries of each scene on their ``proposal``; a model trained on simulated coarse
    proposals (``crop_m`` > 0) sees real ones cut to their densest objects, as in its training."""
    parts = []
    for ref, q in scenes:
        test = q[q["split"] == split]
        props = proposals_module.for_queries(ref, test, proposal, cfg.map_type, coarse, strategy)
        parts.append(evaluate_model(model, cfg, ref, test, proposals_module.crop_to_densest(ref, props, crop_m)))
    return pd.concat(parts, ignore_index=True)


def evaluate_solver(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    map_type: str,
    config: dict | None = None,
    priors: solver.TrainingPriors | None = None,
    method: str = "solver",
    progress: Callable | None = None,
) -> pd.DataFrame:
    """Run the geometric solver on every query of one scene; one row of errors per query.

    ``proposals`` has the shape scene, token, strategy, proposal (reference obj_idx); queries
    without a proposal row get an empty proposal (counted as failures). ``priors``: the scene's
    training priors over the rows of ``ref`` (:func:`flatlandia.solver.scene_priors`), with the
    learned scale prior and verifier for depth maps; None: none.
    """
    cfg = solver.SolverConfig.from_dict(config)
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    lat = float(ref["lat"].mean())
    props = {str(t): (s, p) for t, s, p in zip(proposals["token"], proposals["strategy"], proposals["proposal"])}
    solver.warm_up()  # query times without the kernels' compilation
    rows = []
    items = list(queries.itertuples(index=False))
    for r in progress(items) if progress else items:
        strategy, prop = props.get(str(r.token), ("none", []))
        idx = np.array([pos[int(o)] for o in prop if int(o) in pos], int)
        q = localmaps.local_map(r, map_type)
        t0, c0 = time.perf_counter(), time.process_time()
        sol = (
            solver.locate(
                q,
                np.asarray(r.classes),
                ref_xy[idx],
                ref_cls[idx],
                metric=(map_type == "gt"),
                config=cfg,
                priors=priors.rows(idx) if priors is not None else None,
            ).best
            if len(idx) >= 2
            else None
        )
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        matched = [-1] * len(q)  # per local-map object, the reference obj_idx it was matched to
        if sol is None:
            pose, errors, fit = (np.nan, np.nan, np.nan), (np.inf, 180.0), (0.0, 0, 0)
        else:
            for k, c in sol.inliers:
                matched[k] = int(obj[idx[c]])
            pose = (sol.x, sol.y, sol.theta)
            errors = pose_errors(sol.x, sol.y, sol.theta, r.x_m, r.y_m, np.radians(r.theta_deg))
            truth = [int(o) for o in r.ref_idx]
            correct = sum(int(obj[idx[c]]) == truth[k] for k, c in sol.inliers)
            fit = (sol.confidence, len(sol.inliers), correct)
        rows.append(
            error_row(
                r,
                method=method,
                map_type=map_type,
                strategy=strategy,
                proposal_classes=ref_cls[idx],
                lat=lat,
                pose=pose,
                errors=errors,
                fit=fit,
                seconds=dt,
                cpu_seconds=dc,
                matches=matched,
                probability=sol.probability if sol is not None else 0.0,
                answered=answered(sol, cfg),
            )
        )
    return pd.DataFrame(rows)


def answered(sol, cfg: solver.SolverConfig) -> bool:
    """A pose whose probability is at least ``solver.answer_probability`` (status ok); a pose
    without a probability (NaN) is answered."""
    if sol is None:
        return False
    return bool(not np.isfinite(sol.probability) or sol.probability >= cfg.answer_probability)


def evaluate_model(
    model: nn.Module,
    cfg: models.FineTrainConfig,
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    method: str | None = None,
) -> pd.DataFrame:
    """Run a learned model on every query of one scene; one row of errors per query (the solver's
    columns). Query time is the single-query inference time (batch of one, after building the
    sample; on the model's device, a GPU: with the copies there and back)."""
    import torch

    from flatlandia import device as device_module
    from flatlandia.fine import models
    from flatlandia.plumbing.pyg import Batch

    samples, kept = models.samples_from_queries(ref, queries, proposals, cfg)
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    strat = dict(zip(proposals["token"].astype(str), proposals["strategy"]))
    lat = float(ref["lat"].mean())
    rows = []
    model.eval()
    device = device_module.model_device(model)
    for s, r in zip(samples, kept.itertuples(index=False)):
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            p = model(Batch.from_data_list([s]).to(device)).cpu().numpy()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x, y, th = models.to_world(p, [s], cfg)[0]
        e_m, e_deg = pose_errors(x, y, th, r.x_m, r.y_m, math.radians(r.theta_deg))
        idx = np.array([pos[int(o)] for o in props.get(str(r.token), []) if int(o) in pos], int)
        rows.append(
            error_row(
                r,
                method=method or cfg.model,
                map_type=cfg.map_type,
                strategy=strat.get(str(r.token), "none"),
                proposal_classes=ref_cls[idx],
                lat=lat,
                pose=(x, y, th),
                errors=(e_m, e_deg),
                fit=(float("nan"), 0, 0),
                seconds=dt,
                cpu_seconds=dc,
            )
        )
    return pd.DataFrame(rows)


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
