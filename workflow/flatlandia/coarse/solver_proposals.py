"""Training-free coarse localization: region proposals from the geometric solver (rule coarse_solver).

Why: the solver needs no proposal to find a pose on the whole reference map (its priors come
from the training split only), and its pose says where the query's objects lie. Placing the
query's local map at that pose (depth maps at the solver's scale) ranks every reference object
by its distance to the nearest placed query object of its class, the objects the solver matched
first; objects of classes the query does not see are never proposed (they cannot be its objects).

Strategies, named like the retrieval model's (Table 3): ``N_LM`` and ``2N_LM`` (the N or 2N
best-ranked objects of the best pose, N = query objects) and ``R_30`` (every object of the
query's classes within ``radius_m`` of a placed query object). ``R_30`` also places the query
at alternative poses: the solver run again on the map without the objects earlier poses matched,
kept while its cost is within ``cost_gap`` of the best (a wrong best pose often has a right
runner-up; tuned on the validation split). ``BB``: the GT-BB box built from the solver's matches
and camera instead of the true ones (:func:`flatlandia.proposals.gtbb_indices`), every class: the
region the learned fine models were trained on (they place the camera inside its box; on N_LM
proposals, which hold only the matched objects, the MLP is 2.5-3.5 times worse, validation split).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from flatlandia import config, geo, proposals, solver
from flatlandia.data import localmaps

STRATEGIES = ["N_LM", "2N_LM", "R_30", "BB"]
MAP_TYPES = list(localmaps.LOCAL_MAP_COLUMNS)  # gt, depth
#: the label of its rows in Table 3 (column ``loss``) and of its fine runs
LABEL = "Solver"


@config.settings("coarse.solver", frozen=True)
class SolverProposalConfig:
    """Settings of the solver's proposals: the config section ``coarse.solver`` (each is described in
    config/README.md, ``coarse.solver.*``)."""


@dataclass
class Candidates:
    """One scene's reference map as the solver reads it, with its training priors."""

    xy: np.ndarray  # (N, 2) metres
    cls: np.ndarray  # (N,) class ids
    priors: solver.TrainingPriors | None = None  # over the N rows


def scene_candidates(ref: pd.DataFrame, priors: solver.TrainingPriors | None = None) -> Candidates:
    """The solver's view of a scene: rows of ``ref`` and its priors (:func:`flatlandia.solver.scene_priors`)."""
    return Candidates(ref[["x_m", "y_m"]].to_numpy(float), ref["class_id"].to_numpy(), priors)


def hypotheses(
    query_xy, query_cls, cand: Candidates, metric: bool, settings=None, alternatives: int = 1
) -> list[tuple[solver.Solution, np.ndarray]]:
    """The best pose on the whole map, then up to ``alternatives - 1`` more, each solved on the map
    without the reference objects the earlier poses matched. Each comes with its candidate rows
    (its inliers index them), best first; empty when the solver finds nothing."""
    keep = np.ones(len(cand.xy), bool)
    out = []
    for _ in range(alternatives):
        rows = np.flatnonzero(keep)
        sol = solver.solve(
            query_xy,
            query_cls,
            cand.xy[rows],
            cand.cls[rows],
            metric=metric,
            config=settings,
            priors=cand.priors.rows(rows) if cand.priors is not None else None,
        )
        if sol is None:
            break
        out.append((sol, rows))
        keep[rows[[c for _, c in sol.inliers]]] = False
    return out


def placed(sol: solver.Solution, query_xy) -> np.ndarray:
    """The query's objects in the map frame at the solver's pose (and scale, for depth maps)."""
    return geo.local_to_world(sol.scale * np.asarray(query_xy, float), np.array([sol.x, sol.y]), sol.theta)


def distances(sol: solver.Solution, query_xy, query_cls, cand: Candidates) -> np.ndarray:
    """(N,) metres from each reference object to the nearest placed query object of its class
    (inf for the classes the query does not see)."""
    p = placed(sol, query_xy)
    same = cand.cls[:, None] == np.asarray(query_cls)[None, :]
    d = np.linalg.norm(cand.xy[:, None] - p[None], axis=-1)
    return np.where(same, d, np.inf).min(1)


def propose(hyps, query_xy, query_cls, cand: Candidates, strategy: str, cfg: SolverProposalConfig) -> np.ndarray:
    """Reference rows (sorted) proposed by one strategy from the solver's poses ``hyps`` (best first)."""
    if not hyps:
        return np.zeros(0, int)
    best, best_rows = hyps[0]
    if strategy in ("N_LM", "2N_LM"):
        score = distances(best, query_xy, query_cls, cand)
        score[best_rows[[c for _, c in best.inliers]]] = -1.0  # the matched objects first
        n = len(query_cls) * (1 if strategy == "N_LM" else 2)
        order = np.argsort(score, kind="stable")[:n]
        return np.sort(order[np.isfinite(score[order])])
    if strategy == "R_30":
        near = np.zeros(len(cand.xy), bool)
        for sol, _ in hyps:
            if sol.cost - best.cost <= cfg.cost_gap:
                near |= distances(sol, query_xy, query_cls, cand) <= cfg.radius_m
        return np.flatnonzero(near)
    if strategy == "BB":
        matched = best_rows[[c for _, c in best.inliers]]
        return proposals.gtbb_indices(cand.xy, matched, [best.x, best.y], cfg.bb_enlarge)
    raise ValueError(f"unknown strategy {strategy!r}; known: {STRATEGIES}")


def scene_proposals(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    map_type: str,
    cand: Candidates,
    cfg: SolverProposalConfig,
    settings=None,
) -> pd.DataFrame:
    """One row per (query, strategy) of one scene: the proposal (reference ``obj_idx``), its metrics
    against the query's matched objects (:func:`flatlandia.proposals.proposal_metrics`),
    the best pose's position error (m) and the seconds the query's poses took."""
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    rows = []
    for r in queries.itertuples(index=False):
        q = localmaps.local_map(r, map_type)
        t0 = time.perf_counter()
        hyps = hypotheses(q, np.asarray(r.classes), cand, map_type == "gt", settings, cfg.alternatives)
        seconds = time.perf_counter() - t0
        truth = [pos[int(o)] for o in r.ref_idx]
        pose_error = float(np.hypot(hyps[0][0].x - r.x_m, hyps[0][0].y - r.y_m)) if hyps else float("inf")
        for strategy in STRATEGIES:
            prop = propose(hyps, q, r.classes, cand, strategy, cfg)
            rows.append(
                {
                    "scene": str(r.scene),
                    "token": str(r.token),
                    "loss": LABEL,
                    "map_type": map_type,
                    "strategy": strategy,
                    "proposal": [int(o) for o in obj[prop]],
                    **proposals.proposal_metrics(prop, truth),
                    "pose_error_m": pose_error,
                    "hypotheses": len(hyps),
                    "seconds": seconds,
                }
            )
    return pd.DataFrame(rows)
