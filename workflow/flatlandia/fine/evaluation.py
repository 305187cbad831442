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

from flatlandia import config, geo, paper
from flatlandia.data import localmaps
from flatlandia import solver

if TYPE_CHECKING:  # torch and torch-geometric load in 4 s: only the learned models' evaluation needs them
    from torch import nn

from flatlandia.fine import learned

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


def training_priors(queries: pd.DataFrame, geo_config: dict | None = None):
    """The solver's priors from one scene's training split: (prior cameras (P, 3) as x, y, heading
    in radians, or None when ``camera_prior`` is off; per prior camera the reference ``obj_idx`` it
    saw, for the co-visibility cost, or None). Test queries never contribute."""
    cfg = {**config.section_defaults("fine.geo"), **(geo_config or {})}
    if not cfg["camera_prior"]:
        return None, None
    tr = queries[queries["split"] == "train"]
    prior = np.column_stack([tr["x_m"], tr["y_m"], np.radians(tr["theta_deg"])]).astype(float)
    seen = [np.asarray(v, int) for v in tr["ref_idx"]] if float(cfg["covis_weight"]) > 0 else None
    return prior, seen


def seen_mask(obj_idx, prior_seen) -> np.ndarray | None:
    """(P, N) booleans: prior camera p saw the reference object of row n (``obj_idx``: the rows'
    ids; ``prior_seen``: per prior camera the ``obj_idx`` it saw, from :func:`training_priors`);
    None without co-visibility sets. Ids outside ``obj_idx`` are ignored."""
    if prior_seen is None:
        return None
    pos = {int(o): k for k, o in enumerate(obj_idx)}
    seen = np.zeros((len(prior_seen), len(pos)), bool)
    for k, objs in enumerate(prior_seen):
        seen[k, [pos[int(o)] for o in objs if int(o) in pos]] = True
    return seen


def depth_scale_prior(queries, geo_config: dict | None = None) -> tuple[float, float] | None:
    """The solver's log-scale prior of depth maps (:func:`solver.fit_priors`) from the training
    split of every scene's queries, or None when ``fine.geo.scale_prior`` is off."""
    cfg = {**config.section_defaults("fine.geo"), **(geo_config or {})}
    if not cfg["scale_prior"]:
        return None
    train = [localmaps.xy(c) for q in queries for c in q.loc[q["split"] == "train", "gt_local_xy_m"]]
    return solver.fit_priors(train)


def solvable(query_classes, proposal_classes, min_objects: int = 3) -> bool:
    """Can the proposal hold a solution: at least ``min_objects`` objects of the query's classes.

    Counted as a multiset match: each query object can use one proposal object of its class.
    """
    need = pd.Series(list(query_classes)).value_counts()
    have = pd.Series(list(proposal_classes)).value_counts()
    usable = sum(min(int(n), int(have.get(c, 0))) for c, n in need.items())
    return usable >= min_objects


# ----------------------------------------------------------------------------- errors


def pose_errors(x, y, theta_rad, gt_x, gt_y, gt_theta_rad):
    """Position error (m) and absolute wrapped heading error (deg); vectorised."""
    e_m = np.hypot(np.asarray(x, float) - gt_x, np.asarray(y, float) - gt_y)
    e_deg = np.abs(np.degrees(geo.wrap_angle(np.asarray(theta_rad, float) - np.asarray(gt_theta_rad, float))))
    return e_m, e_deg


@functools.lru_cache(maxsize=256)
def metres_per_unit(lat: float) -> float:
    """Mean true metres per published local-map unit (tf/2 degrees) at a latitude (cached: a
    projection is built per call, 18 ms, and evaluation asks once per query)."""
    mx, my = geo.MetricFrame(0.0, float(lat)).metres_per_degree()
    return geo.UNIT_DEG * (mx + my) / 2


def paper_metres(error_m, lat: float):
    """A true-metre error in the paper's convention (local-map units x 215)."""
    return np.asarray(error_m, float) / metres_per_unit(lat) * paper.METRES_PER_UNIT


def summarise(errors: pd.DataFrame) -> dict:
    """Median errors, % under the paper's thresholds, the field's recalls (position and heading
    apart), F%, gross share, mean/median query time.

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
    out["failure_pct"] = float(100 * np.mean(~e["solvable"].to_numpy(bool))) if len(e) else float("nan")
    out["no_pose_pct"] = float(100 * np.mean(~np.isfinite(em))) if len(e) else float("nan")
    out["gross_pct"] = float(100 * np.mean(em > GROSS_M)) if len(e) else float("nan")
    out["mean_query_s"] = float(e["seconds"].mean()) if len(e) else float("nan")
    out["median_query_s"] = float(e["seconds"].median()) if len(e) else float("nan")
    if "cpu_seconds" in e:  # CPU time of the process: robust to other load on a shared machine
        out["median_query_cpu_s"] = float(e["cpu_seconds"].median()) if len(e) else float("nan")
    if "error_paper_m" in e:  # the paper's convention: local-map units x 215, same thresholds
        pu = e["error_paper_m"].to_numpy(float)
        out["median_pu"] = float(np.median(pu)) if len(e) else float("nan")
        for column, (m, d) in zip(PAPER_UNIT_THRESHOLD_COLUMNS, paper.THRESHOLDS):
            out[column] = float(100 * np.mean((pu < m) & (ed < d))) if len(e) else float("nan")
    return out


def ref_map_kb(ref: pd.DataFrame) -> float:
    """Size of a reference map as the methods read it: 2 x float32 + a class byte per object, kB."""
    return 9 * len(ref) / 1000


def json_safe(d: dict) -> dict:
    """Non-finite floats as None (JSON has no inf/NaN)."""
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


# ----------------------------------------------------------------------------- solver evaluation


def evaluate_solver(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    map_type: str,
    config: dict | None = None,
    prior_xy: np.ndarray | None = None,
    scale_prior: tuple[float, float] | None = None,
    method: str = "solver",
    progress: Callable | None = None,
    prior_seen: list | None = None,
    verifier: solver.Verifier | None = None,
) -> pd.DataFrame:
    """Run the geometric solver on every query of one scene; one row of errors per query.

    ``proposals`` has the shape scene, token, strategy, proposal (reference obj_idx); queries
    without a proposal row get an empty proposal (counted as failures). ``prior_seen``: per prior
    camera (rows of ``prior_xy``), the reference ``obj_idx`` it saw (training queries' ``ref_idx``),
    for the solver's co-visibility cost. ``verifier``: the solver's verifier for depth maps
    (``verify_fit.fit_verifier``), or None to keep the cheapest hypothesis.
    """
    cfg = solver.SolverConfig.from_dict(config)
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    lat = float(ref["lat"].mean())
    props = {str(t): (s, p) for t, s, p in zip(proposals["token"], proposals["strategy"], proposals["proposal"])}
    seen = seen_mask(obj, prior_seen) if prior_xy is not None else None
    solver.warm_up()  # query times without the kernels' compilation
    rows = []
    items = list(queries.itertuples(index=False))
    for r in progress(items) if progress else items:
        strategy, prop = props.get(str(r.token), ("none", []))
        idx = np.array([pos[int(o)] for o in prop if int(o) in pos], int)
        q = localmaps.local_map(r, map_type)
        t0, c0 = time.perf_counter(), time.process_time()
        sol = (
            solver.solve(
                q,
                np.asarray(r.classes),
                ref_xy[idx],
                ref_cls[idx],
                metric=(map_type == "gt"),
                config=cfg,
                prior_xy=prior_xy,
                scale_prior=scale_prior,
                prior_seen=seen[:, idx] if seen is not None else None,
                verifier=verifier,
            )
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
            )
        )
    return pd.DataFrame(rows)


def evaluate_model(
    model: nn.Module,
    cfg: learned.FineConfig,
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    method: str | None = None,
) -> pd.DataFrame:
    """Run a learned model on every query of one scene; one row of errors per query (the solver's
    columns). Query time is the single-query inference time (batch of one, after building the
    sample)."""
    import torch
    from torch_geometric.data import Batch

from flatlandia.fine import learned

    samples, kept = learned.samples_from_queries(ref, queries, proposals, cfg)
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    strat = dict(zip(proposals["token"].astype(str), proposals["strategy"]))
    lat = float(ref["lat"].mean())
    rows = []
    model.eval()
    for s, r in zip(samples, kept.itertuples(index=False)):
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            p = model(Batch.from_data_list([s])).numpy()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x, y, th = learned.to_world(p, [s], cfg)[0]
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
) -> dict:
    """One query's row of an errors table. Why one function: the solver's and the learned models'
    rows must share their columns, which fine_table reads alike.

    ``query``: the query row; ``pose``: (x, y, heading in radians), NaN without a pose;
    ``errors``: (metres, degrees); ``fit``: the solver's (confidence, inliers, correct inliers);
    ``matches``: the solver's reference ``obj_idx`` per local-map object (-1: unmatched), for the
    figures and the viewer; empty for learned models, which match nothing.
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
    }
