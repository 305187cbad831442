"""Fitting the answers' calibration (:mod:`flatlandia.solver.calibration`) on the validation split.

Why the validation split: the probability must be right on queries the solver never learned from,
and the training split's queries are in the priors (their cameras, what they saw). The solver,
with every learned prior but the calibration, answers each validation query on its region (one
frame, as rule fine_eval) and, on the whole map, each validation anchor's sequences (as rule
beyond_scene, at every frame count of ``beyond.frames`` above one); each answer's pool share and
whether it came out within (5 m, 5 deg) are what the logistic maps learn from. Rule solver_priors
runs it once per benchmark (docs/measurements.md, "Code paths").
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia.solver import learned as learned_module
from flatlandia.solver.calibration import RIGHT_DEG, RIGHT_M
from flatlandia.solver.learned import LearnedPriors

#: the split the cities' map-size correction is fitted on (rule city_calibration)
CITY_SPLIT = "val"


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
    from flatlandia.beyond import evaluate as beyond_evaluate
    from flatlandia.fine import evaluation

    raw = learned if learned.calibration is None else LearnedPriors(learned.scale, learned.verifier, learned.likelihood)
    one = evaluation.solver_errors(scenes, "depth", region, settings, raw, split=split)
    parts = [_answers(one, np.ones(len(one), int))]
    if beyond is not None and region == "whole":
        grid = [beyond_evaluate.Setting(int(k)) for k in beyond["frames"] if int(k) > 1]
        if grid:
            seq = beyond_evaluate.scene_errors(scenes, grid, settings, beyond, raw, seed, split)
            seq = seq[seq["frames_used"] > 1] if len(seq) else seq
            if len(seq):
                parts.append(_answers(seq, seq["frames_used"].to_numpy(int)))
    return pd.concat(parts, ignore_index=True)


def _answers(errors: pd.DataFrame, frames: np.ndarray) -> pd.DataFrame:
    """The answers with a pose (a query without one has no probability to calibrate)."""
    em, ed = errors["error_m"].to_numpy(float), errors["error_deg"].to_numpy(float)
    posed = np.isfinite(em)
    return pd.DataFrame(
        {
            "frames": frames,
            "objects": errors["n_objects"].to_numpy(int),
            "pool_share": errors["probability"].to_numpy(float),
            "agreement": errors["agreement"].fillna(1.0).to_numpy(float) if "agreement" in errors else 1.0,
            "right": (em < RIGHT_M) & (ed < RIGHT_DEG),
        }
    )[posed].reset_index(drop=True)


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
    return learned_module.with_calibration(learned, answers), answers


def city_answers(errors: pd.DataFrame, map_objects: float) -> pd.DataFrame:
    """The answers of a city's anchors (rows of :mod:`flatlandia.beyond.evaluate`, without a fix)
    for the map-size fit (:func:`flatlandia.solver.calibration.fit_map_size`): ``map``, ``frames``
    (used), ``map_objects`` (the objects the index ranked), ``probability`` (calibrated, before the
    correction), ``right``; the anchors without a pose are left out."""
    e = errors[errors["gps_sigma_m"].isna()] if "gps_sigma_m" in errors else errors
    em, ed = e["error_m"].to_numpy(float), e["error_deg"].to_numpy(float)
    posed = np.isfinite(em)
    return pd.DataFrame(
        {
            "map": e["map"].astype(str).to_numpy(),
            "frames": e["frames_used"].to_numpy(int),
            "map_objects": np.full(len(e), float(map_objects)),
            "probability": e["probability"].to_numpy(float),
            "right": (em < RIGHT_M) & (ed < RIGHT_DEG),
        }
    )[posed].reset_index(drop=True)
