"""The probability that an answer is right, from the log-odds of its pose against the others.

Why: a solver that answers every query cannot say when it is wrong, and a ranking score (the
verifier's, the joint cost) is no probability. Every pool of refined poses the solver ranks
carries its own log-odds: the ranking key of each pose is a negative log-likelihood (the MSAC cost
halved, or the verifier's conditional logit, plus the likelihood ratio against chance,
:mod:`flatlandia.solver.likelihood`), so the softmax of the keys over the pool is each pose's share
of the evidence, and the share of the poses within (5 m, 5 deg) of a pose (:func:`pose_masses`) is
how sure the pool is of that place. That share is sharper or flatter than the truth (the pool is
a dozen poses, not every place, and the keys are not exact likelihoods), so a logistic regression
(:class:`Calibration`, scikit-learn) maps its log-odds and the number of objects seen to the
probability of being within (5 m, 5 deg), fitted on the validation split (rule solver_priors, one
fit for single frames and one for sequences) and written with the learned priors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: an answer within this of the truth is right (the headline's (5 m, 5 deg))
RIGHT_M, RIGHT_DEG = 5.0, 5.0
#: the features of the calibration, in order
FEATURES = ("log_odds", "log_objects", "log_frames", "agreement")
#: log-odds of a share are clipped to this (a pool of one pose is sure of itself, not infinitely)
MAX_LOG_ODDS = 20.0
#: the answer kinds calibrated apart: one frame, and a sequence of several
KINDS = ("frame", "sequence")


def pose_masses(t, theta, key, ok=None) -> np.ndarray:
    """(C,) each pose's share of the pool's evidence: the softmax of ``-key`` (C,) over the poses
    where ``ok``, summed over the poses within (:data:`RIGHT_M`, :data:`RIGHT_DEG`) of it; 0 where
    not ``ok``."""
    t = np.asarray(t, float).reshape(-1, 2)
    theta = np.asarray(theta, float).ravel()
    key = np.asarray(key, float).ravel()
    ok = np.isfinite(key) if ok is None else np.asarray(ok, bool) & np.isfinite(key)
    out = np.zeros(len(key))
    if not ok.any():
        return out
    w = np.where(ok, np.exp(-(key - key[ok].min())), 0.0)
    w /= w.sum()
    dist = np.hypot(t[:, None, 0] - t[None, :, 0], t[:, None, 1] - t[None, :, 1])
    turn = np.abs((theta[:, None] - theta[None, :] + np.pi) % (2 * np.pi) - np.pi)
    near = (dist < RIGHT_M) & (turn < math.radians(RIGHT_DEG))
    out[ok] = (near[ok] * w[None]).sum(1)
    return np.clip(out, 0.0, 1.0)


def features(mass, objects, frames=1, agreement=1.0) -> np.ndarray:
    """(N, 4) the calibration's features (:data:`FEATURES`) of answers with pool shares ``mass``,
    ``objects`` objects seen by the anchor frame, of ``frames`` frames of which a share
    ``agreement`` answered alone the same place (1 for a single frame)."""
    mass = np.clip(np.asarray(mass, float).ravel(), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        lo = np.log(mass) - np.log1p(-mass)
    lo = np.clip(np.nan_to_num(lo, nan=-MAX_LOG_ODDS), -MAX_LOG_ODDS, MAX_LOG_ODDS)
    objects = np.broadcast_to(np.asarray(objects, float).ravel(), mass.shape)
    frames = np.broadcast_to(np.asarray(frames, float).ravel(), mass.shape)
    agreement = np.broadcast_to(np.asarray(agreement, float).ravel(), mass.shape)
    return np.column_stack([lo, np.log(np.maximum(objects, 1.0)), np.log(frames), agreement])


@dataclass(frozen=True)
class Logistic:
    """P(right) = sigmoid(intercept + weights . features)."""

    intercept: float
    weights: tuple[float, ...]
    answers: int  # validation answers it was fitted on

    def __post_init__(self):
        if len(self.weights) != len(FEATURES) or not all(math.isfinite(w) for w in (self.intercept, *self.weights)):
            raise ValueError(f"a calibration needs {len(FEATURES)} finite weights and an intercept, got {self}")

    def __call__(self, x: np.ndarray) -> np.ndarray:
        z = self.intercept + np.asarray(x, float) @ np.asarray(self.weights, float)
        return 1.0 / (1.0 + np.exp(-z))


@dataclass(frozen=True)
class Calibration:
    """The fitted maps of single frames and of sequences (either None: the pool's share is used as
    it is)."""

    frame: Logistic | None = None
    sequence: Logistic | None = None

    def probability(self, mass, objects, frames: int = 1, agreement=1.0) -> np.ndarray:
        """(N,) P(within (5 m, 5 deg)) of answers with pool shares ``mass`` and ``objects`` seen, of
        ``frames`` frames of which a share ``agreement`` answered alone the same place."""
        fit = self.frame if frames <= 1 else self.sequence
        mass = np.clip(np.asarray(mass, float).ravel(), 0.0, 1.0)
        return mass if fit is None else fit(features(mass, objects, frames, agreement))

    def to_dict(self) -> dict:
        out = {"features": list(FEATURES)}
        for k in KINDS:
            f = getattr(self, k)
            out[k] = None if f is None else {"intercept": f.intercept, "weights": list(f.weights), "answers": f.answers}
        return out

    @classmethod
    def from_dict(cls, d: dict) -> Calibration:
        if d.get("features") != list(FEATURES):
            raise ValueError(f"the calibration's features {d.get('features')} are not {list(FEATURES)}")
        parts = {}
        for k in KINDS:
            v = d.get(k)
            parts[k] = (
                None
                if v is None
                else Logistic(float(v["intercept"]), tuple(float(w) for w in v["weights"]), int(v["answers"]))
            )
        return cls(**parts)


def probability(calibration: Calibration | None, mass, objects, frames: int = 1, agreement=1.0) -> np.ndarray:
    """:meth:`Calibration.probability`, or the share itself without a calibration."""
    if calibration is None:
        return np.clip(np.asarray(mass, float).ravel(), 0.0, 1.0)
    return calibration.probability(mass, objects, frames, agreement)


def fit_logistic(mass, objects, frames, agreement, right) -> Logistic | None:
    """The logistic map of answers (pool share, objects the anchor saw, frames, the frames' agreement,
    right or not); None with fewer than 20 answers or a single outcome. scikit-learn's lbfgs, L2
    (C = 1): deterministic."""
    from sklearn.linear_model import LogisticRegression

    y = np.asarray(right, bool).ravel()
    if len(y) < 20 or y.all() or not y.any():
        return None
    lr = LogisticRegression(C=1.0, max_iter=5000).fit(features(mass, objects, frames, agreement), y)
    return Logistic(float(lr.intercept_[0]), tuple(float(w) for w in lr.coef_.ravel()), int(len(y)))


def expected_calibration_error(probability, right, bins: int = 10) -> float:
    """Expected calibration error in points (0-100): the answers binned by probability into
    ``bins`` equal bins, the mean |probability - share right| weighted by the bins' sizes."""
    p = np.asarray(probability, float).ravel()
    y = np.asarray(right, float).ravel()
    if not len(p):
        return float("nan")
    b = np.minimum((p * bins).astype(int), bins - 1)
    total = sum(abs(p[b == k].mean() - y[b == k].mean()) * (b == k).sum() for k in range(bins) if (b == k).any())
    return float(100 * total / len(p))


def risk_coverage(probability, bad) -> tuple[np.ndarray, np.ndarray]:
    """(coverage, risk) in %: answering the answers of the highest probability first, the share
    answered and the share of those answered that are ``bad`` (wrong, or in the wrong scene), at
    every cut (ties broken by order)."""
    p = np.asarray(probability, float).ravel()
    bad = np.asarray(bad, bool).ravel()
    order = np.argsort(-p, kind="stable")
    n = np.arange(1, len(p) + 1)
    return 100 * n / max(len(p), 1), 100 * np.cumsum(bad[order]) / n


def largest_coverage(probability, bad, max_risk_pct: float) -> float:
    """The largest share answered (%) at which at most ``max_risk_pct`` % of the answered are bad
    (answering by decreasing probability; 0 when even the surest answer is bad)."""
    if not len(np.asarray(probability).ravel()):
        return float("nan")
    cov, risk = risk_coverage(probability, bad)
    ok = np.flatnonzero(risk <= max_risk_pct + 1e-9)
    return float(cov[ok.max()]) if len(ok) else 0.0
