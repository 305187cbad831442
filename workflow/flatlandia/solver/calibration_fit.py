"""What the answers' calibration (:mod:`flatlandia.solver.calibration`) is fitted on: the answers of
an errors table, each with its pool share and whether it was right.

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

from flatlandia.solver.calibration import RIGHT_DEG, RIGHT_M

#: the split the cities' map-size correction is fitted on (rule city_calibration)
CITY_SPLIT = "val"


def answers(errors: pd.DataFrame, frames: np.ndarray) -> pd.DataFrame:
    """The answers with a pose of an errors table (a query without one has no probability to
    calibrate): ``frames`` (used), ``objects``, ``pool_share``, ``agreement``, ``right``."""
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


def city_answers(errors: pd.DataFrame, map_objects: float) -> pd.DataFrame:
    """The answers of a city's anchors (rows of :mod:`flatlandia.sequences.evaluation`, without a fix)
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
