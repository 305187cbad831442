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

from flatlandia.solver import calibration
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


#: the nonsense answers' total weight in the null hypothesis' fit, as a share of the real answers'
#: (on the validation split 0.25 left 1.6 % of the nonsense queries `ok`, 0.5 0.8 %, 1.0 0.7 %, the
#: real answers' calibration error rising with it: 6.2, 7.9, 11.1 points; docs/results.md)
NONSENSE_WEIGHT = 0.5
#: the null keys tried (:func:`fit_null`): this many, evenly over the pools' evidence and beyond
NULL_GRID = 61


def fit_null(evidence: pd.DataFrame) -> tuple[float | None, calibration.Logistic | None]:
    """(null key, the single frames' logistic map) fitted on ``evidence``: one row per answer of a
    validation query (``nonsense`` empty) or of a nonsense query (:mod:`flatlandia.solver.nonsense`,
    ``nonsense`` its kind, never right), columns ``log_place``, ``log_pool``, ``objects``, ``right``.

    Each null key of a grid over the pools' evidence gives each answer its share with the null
    hypothesis (:func:`calibration.null_share`) and a logistic fit on the real and nonsense answers
    together (the nonsense weighing :data:`NONSENSE_WEIGHT` of the real ones: a user's queries are
    mostly real, and the probability must learn what a share that fits nowhere looks like, which no
    real validation query shows); the key and fit of the highest weighted likelihood win (no key
    where none fits better than no null hypothesis). (None, None) with too few answers."""
    from sklearn.linear_model import LogisticRegression

    e = evidence[np.isfinite(evidence["log_place"].to_numpy(float))]
    y = e["right"].to_numpy(bool)
    fake = e["nonsense"].fillna("").astype(str).to_numpy() != ""
    real = ~fake
    if real.sum() < 20 or not y[real].any() or (y[real].all() and not fake.any()):
        return None, None  # the nonsense answers are wrong answers too: with them, all-right real ones fit
    w = np.where(fake, NONSENSE_WEIGHT * real.sum() / max(fake.sum(), 1), 1.0)
    lp, lq = e["log_place"].to_numpy(float), e["log_pool"].to_numpy(float)
    objects = e["objects"].to_numpy(float)

    def fitted(null_key):
        x = calibration.features(calibration.null_share(lp, lq, null_key), objects)
        lr = LogisticRegression(C=1.0, max_iter=5000).fit(x, y, sample_weight=w)
        p = np.clip(lr.predict_proba(x)[:, 1], 1e-12, 1 - 1e-12)
        loss = -float(np.sum(w * np.where(y, np.log(p), np.log1p(-p))))
        fit = calibration.Logistic(float(lr.intercept_[0]), tuple(float(v) for v in lr.coef_.ravel()), int(real.sum()))
        return loss, fit

    best_key, (best_loss, best_fit) = None, fitted(None)
    lo, hi = float(np.min(-lq)) - 5.0, float(np.max(-lq)) + 5.0
    for key in np.linspace(lo, hi, NULL_GRID):
        loss, fit = fitted(float(key))
        if loss < best_loss - 1e-9:
            best_key, best_loss, best_fit = float(key), loss, fit
    return best_key, best_fit
