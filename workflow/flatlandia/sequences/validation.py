"""The solver's answers on the validation split, one frame and sequences: what the answers'
calibration is fitted on (:mod:`flatlandia.solver.calibration_fit`, rule solver_priors).

Why here, above the fine stage and the sequences: the answers are the fine stage's one-frame
errors (:func:`flatlandia.fine.evaluation.solver_errors`) and the sequences' errors
(:func:`flatlandia.sequences.evaluation.scene_errors`) of the solver run without calibration.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia.fine import evaluation
from flatlandia.sequences import evaluation as sequence_evaluation
from flatlandia.solver import calibration_fit, learned_priors
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
    raw = learned if learned.calibration is None else LearnedPriors(learned.scale, learned.verifier, learned.likelihood)
    one = evaluation.solver_errors(scenes, "depth", region, settings, raw, split=split)
    parts = [calibration_fit.answers(one, np.ones(len(one), int))]
    if beyond is not None and region == "whole":
        grid = [sequence_evaluation.Setting(int(k)) for k in beyond["frames"] if int(k) > 1]
        if grid:
            seq = sequence_evaluation.scene_errors(scenes, grid, settings, beyond, raw, seed, split)
            seq = seq[seq["frames_used"] > 1] if len(seq) else seq
            if len(seq):
                parts.append(calibration_fit.answers(seq, seq["frames_used"].to_numpy(int)))
    return pd.concat(parts, ignore_index=True)


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
