"""The solver's answers on the validation split, one frame and sequences: what the answers'
calibration is fitted on (:mod:`flatlandia.solver.calibration_fit`, rule solver_priors).

Why here, above the fine stage and the sequences: the answers are the fine stage's one-frame
errors (:func:`flatlandia.benchmark.solver_runs.solver_errors`) and the sequences' errors
(:func:`flatlandia.sequences.evaluation.scene_errors`) of the solver run without calibration.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from flatlandia import proposals, solver
from flatlandia.benchmark import solver_runs
from flatlandia.data import localmaps
from flatlandia.sequences import evaluation as sequence_evaluation
from flatlandia.solver import calibration_fit, learned_priors, nonsense
from flatlandia.solver.calibration import RIGHT_DEG, RIGHT_M, Calibration
from flatlandia.solver.learned_priors import LearnedPriors


def validation_answers(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    learned: LearnedPriors,
    region: str = "whole",
    beyond: dict | None = None,
    seed: int = 0,
    split: str = "val",
) -> pd.DataFrame:
    """The solver's answers to the ``split`` queries of ``scenes`` (reference map, queries) with
    ``learned`` (no calibration: each answer's probability is its pool share): one frame on
    ``region`` and, given the protocol ``beyond`` (config section ``beyond``), the whole map's
    sequences. Columns ``frames`` (used), ``objects`` (the anchor's), ``pool_share``, ``agreement``
    (the share of a sequence's frames whose own answer is its place; 1 for one frame), ``right``."""
    raw = replace(learned, calibration=None)
    one = solver_runs.solver_errors(scenes, "depth", region, settings, raw, split=split)
    parts = [calibration_fit.answers(one, np.ones(len(one), int))]
    if beyond is not None and region == "whole":
        grid = [sequence_evaluation.Setting(int(k)) for k in beyond["frames"] if int(k) > 1]
        for level in beyond.get("calibration_noise", [1.0]) if grid else []:
            seq = sequence_evaluation.scene_errors(scenes, grid, settings, noisier(beyond, level), raw, seed, split)
            seq = seq[seq["frames_used"] > 1] if len(seq) else seq
            if len(seq):
                parts.append(calibration_fit.answers(seq, seq["frames_used"].to_numpy(int)))
    return pd.concat(parts, ignore_index=True)


def noisier(beyond: dict, level: float) -> dict:
    """The protocol ``beyond`` with its odometry noise (``odometry_distance_pct``,
    ``odometry_heading_deg``) times ``level``."""
    return {
        **beyond,
        "odometry_distance_pct": float(beyond["odometry_distance_pct"]) * float(level),
        "odometry_heading_deg": float(beyond["odometry_heading_deg"]) * float(level),
    }


def frame_evidence(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    learned: LearnedPriors,
    region: str = "whole",
    seed: int = 0,
    split: str = "val",
    map_type: str = "depth",
) -> pd.DataFrame:
    """The evidence of every single-frame answer to the ``split`` queries of ``scenes`` on their
    ``region`` and to as many nonsense queries of each kind (:func:`nonsense.draw`, seeded by
    ``seed``) on the whole map, solved with ``learned`` without calibration (None: the training
    cameras alone, as GT local maps are solved): columns ``nonsense`` (the kind, "" for a real
    query), ``objects``, ``log_place``, ``log_pool``, ``right`` (what :func:`calibration_fit.fit_null`
    fits). ``map_type``: the local maps asked, depth or gt (metres)."""
    raw = replace(learned, calibration=None) if learned is not None else None
    metric = map_type == "gt"
    cfg = solver.SolverConfig.of(settings)
    solver.warm_up()
    rows, real, priors = [], [], []
    for ref, q in scenes:
        part = q[q["split"] == split]
        props = proposals.for_queries(ref, part, region, map_type)
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
        regions = dict(zip(props["token"].astype(str), props["proposal"]))
        priors.append(solver.scene_priors(ref, q, settings, raw))
        records = [r for _, r in part.iterrows()]
        real.append([(localmaps.local_map(r, map_type), np.asarray(r["classes"])) for r in records])
        for (xy, cls), r in zip(real[-1], records):
            idx = np.array([pos[int(o)] for o in regions.get(str(r["token"]), []) if int(o) in pos], int)
            sol = _solve(ref, idx, xy, cls, cfg, priors[-1], metric)
            right = sol is not None and _right(sol, r)
            rows.append(_evidence_row("", len(cls), sol, right))
    for n in nonsense.draw(real, [ref["class_id"].to_numpy() for ref, _ in scenes], seed, metric=metric):
        ref = scenes[n.scene][0]
        sol = _solve(ref, np.arange(len(ref)), n.xy, n.classes, cfg, priors[n.scene], metric)
        rows.append(_evidence_row(n.kind, len(n.classes), sol, False))
    return pd.DataFrame(rows)


def _solve(ref, idx, xy, cls, cfg, priors, metric: bool = False):
    if len(idx) < 2:
        return None
    r = ref.iloc[idx]
    return solver.locate(
        xy, cls, r[["x_m", "y_m"]].to_numpy(), r["class_id"].to_numpy(), metric, cfg, priors.rows(idx)
    ).best


def _right(sol, r) -> bool:
    from flatlandia import geo

    e_m, e_deg = geo.pose_errors(sol.x, sol.y, sol.theta, r["x_m"], r["y_m"], np.radians(r["theta_deg"]))
    return bool(e_m < RIGHT_M and e_deg < RIGHT_DEG)


def _evidence_row(kind: str, objects: int, sol, right: bool) -> dict:
    none = sol is None or sol.log_place is None
    return {
        "nonsense": kind,
        "objects": int(objects),
        "log_place": -np.inf if none else float(sol.log_place),
        "log_pool": -np.inf if none else float(sol.log_pool),
        "right": bool(right),
    }


def with_null(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    learned: LearnedPriors,
    region: str = "whole",
    seed: int = 0,
    split: str = "val",
) -> tuple[LearnedPriors, pd.DataFrame]:
    """(``learned`` with the single frames' null hypothesis and their logistic map refitted on the
    validation and nonsense answers, the evidence): :func:`frame_evidence`, then
    :func:`calibration_fit.fit_null`; unchanged where no null hypothesis fits better."""
    evidence = frame_evidence(scenes, settings, learned, region, seed, split)
    null_key, frame = calibration_fit.fit_null(evidence)
    if null_key is None or learned.calibration is None:
        return learned, evidence
    return replace(learned, calibration=replace(learned.calibration, frame=frame, null_key=null_key)), evidence


def calibrated(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    learned: LearnedPriors,
    region: str = "whole",
    beyond: dict | None = None,
    seed: int = 0,
    split: str = "val",
) -> tuple[LearnedPriors, pd.DataFrame]:
    """(``learned`` with the calibration fitted on the validation answers, the answers)."""
    answers = validation_answers(scenes, settings, learned, region, beyond, seed, split)
    return learned_priors.with_calibration(learned, answers), answers


def gt_calibration(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    seed: int = 0,
    split: str = "val",
) -> tuple[LearnedPriors | None, pd.DataFrame]:
    """(the priors of GT local maps: their single frames' calibration with its null hypothesis,
    None where none fits; the evidence): :func:`frame_evidence` on the ``split``'s GT maps and
    nonsense queries in metres, solved as GT maps are (training cameras, nothing learned), then
    :func:`calibration_fit.fit_null`. Why: without it a GT answer's probability was its pool's
    share alone, and random layouts came back ``ok`` (28 % of them on val)."""
    evidence = frame_evidence(scenes, settings, None, "whole", seed, split, map_type="gt")
    null_key, frame = calibration_fit.fit_null(evidence)
    if frame is None:
        return None, evidence
    return LearnedPriors(calibration=Calibration(frame=frame, null_key=null_key)), evidence
