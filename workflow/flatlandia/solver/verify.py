"""Verification: which of the solver's best refined hypotheses is the right pose.

Why: on the whole map the cheapest hypothesis is often wrong while a near-tie is right (a pose within
(5 m, 5 deg) is among the 12 cheapest refined hypotheses far more often than it is the cheapest:
docs/measurements.md, "Geometric solver"). What separates them is evidence the MSAC
cost weighs poorly or not at all: how well the matched objects agree with what the training
cameras near the pose saw (Jaccard overlap, visibility, objects seen there but not matched),
how dense the training cameras are there, and the cost's own terms. A linear score of these
features (:class:`Verifier`) is learned from the training split (:mod:`flatlandia.solver.verify_fit`) and
picks the hypothesis with the highest score.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flatlandia import geo
from flatlandia.solver.priors import Priors
from flatlandia.solver.problem import Problem

#: the features of a hypothesis, in the columns of :func:`features`
FEATURES = (
    "data_cost",  # capped MSAC data term (bearings and log-ranges)
    "prior_cost",  # camera (position, heading) and scale prior costs
    "uncovered",  # inliers that the best single training camera nearby did not see
    "jaccard",  # best overlap of the matched objects with one nearby training camera's objects
    "visibility",  # mean log share of nearby training cameras that saw each matched object
    "density",  # log kernel density of the training cameras at the pose
    "unseen",  # objects the nearby training cameras saw that the pose does not match (expected count)
    "camera_m",  # distance to the nearest training camera
    "log_scale",  # log metres per local unit
)
#: kernel of "nearby" training cameras: position and heading widths, radius (other widths choose
#: alike: docs/measurements.md, "Geometric solver")
KERNEL_M, KERNEL_DEG, KERNEL_RADIUS_M = 5.0, 30.0, 15.0
#: training cameras looked at per hypothesis
KERNEL_KNN = 32
#: floor of a visibility share (an object no nearby camera saw is unlikely, not impossible)
VISIBILITY_FLOOR = 0.05


@dataclass(frozen=True)
class Verifier:
    """A linear score of standardised features; higher is more likely the right pose."""

    weights: np.ndarray  # (F,)
    mean: np.ndarray  # (F,) of the training features
    scale: np.ndarray  # (F,)

    def score(self, f: np.ndarray) -> np.ndarray:
        """(C,) scores of hypotheses with features ``f`` (C, F)."""
        return ((f - self.mean) / self.scale) @ self.weights


def usable(problem: Problem, priors: Priors) -> bool:
    """The features need a depth map, training cameras and what they saw."""
    return not problem.metric and priors.tree is not None and priors.seen is not None


def features(problem: Problem, priors: Priors, t, theta, s, data, inl, match) -> np.ndarray:
    """(C, F) features of refined hypotheses (``t``, ``theta``, ``s``) whose capped data cost,
    inliers and matches are ``data``, ``inl``, ``match`` (from ``scoring.data_cost``)."""
    t = np.asarray(t, float).reshape(-1, 2)
    n = len(t)
    k = min(KERNEL_KNN, priors.tree.n)
    d, j = priors.tree.query(t, k=k, distance_upper_bound=KERNEL_RADIUS_M)
    d, j = d.reshape(n, k), np.minimum(j, priors.tree.n - 1).reshape(n, k)  # missing: d = inf
    seen = priors.seen[j]  # (C, k, N) what each nearby camera saw
    matched = np.zeros((n, seen.shape[2]), bool)  # (C, N) the matched objects
    rows = np.repeat(np.arange(n), problem.m)
    matched[rows[inl.ravel()], match.ravel()[inl.ravel()]] = True
    # Jaccard overlap with the best camera within the co-visibility radius
    inter = np.einsum("ckn,cn->ck", seen, matched, dtype=np.int64)
    union = seen.sum(2) + matched.sum(1)[:, None] - inter
    near = d <= priors.cfg.covis_radius_m
    jaccard = np.where(near, inter / np.maximum(union, 1), 0.0).max(1)
    # kernel-weighted share of nearby cameras that saw each object
    dth = geo.wrap_angle(priors.heading[j] - np.asarray(theta).reshape(-1, 1)) if priors.heading is not None else 0.0
    w = np.where(np.isfinite(d), np.exp(-0.5 * (d / KERNEL_M) ** 2 - 0.5 * (dth / np.radians(KERNEL_DEG)) ** 2), 0.0)
    total = w.sum(1)
    share = np.einsum("ck,ckn->cn", w, seen) / np.maximum(total, 1e-12)[:, None]
    at_match = np.log(VISIBILITY_FLOOR + np.take_along_axis(share, match, 1))
    n_inl = inl.sum(1)
    visibility = np.where(n_inl > 0, (at_match * inl).sum(1) / np.maximum(n_inl, 1), np.log(VISIBILITY_FLOOR))
    unseen = share.sum(1) - (share * matched).sum(1)
    covered = priors.covis_counts((d, j), match, inl)
    nb = priors.neighbours(t)
    return np.column_stack(
        [
            data,
            priors.cost(t, s, theta, nb),
            n_inl - covered,
            jaccard,
            visibility,
            np.log(total + 1e-6),
            unseen,
            np.minimum(d[:, 0], KERNEL_RADIUS_M),
            np.log(s),
        ]
    )


def fit(groups: list[tuple[np.ndarray, np.ndarray]], l2: float = 1e-2) -> Verifier:
    """The verifier that best picks a right hypothesis: a conditional logit (softmax over each
    query's hypotheses) fitted by L-BFGS from zero weights (deterministic). ``groups``: per training
    query, its hypotheses' features (C, F) and which of them are right (C,) bool; queries without a
    right hypothesis carry no information and are left out."""
    groups = [(f, y) for f, y in groups if len(f) and np.any(y)]
    if not groups:
        raise ValueError("no training query has a right hypothesis to learn from")
    x = np.vstack([f for f, _ in groups])
    y = np.concatenate([np.asarray(g, float) for _, g in groups])
    gi = np.repeat(np.arange(len(groups)), [len(f) for f, _ in groups])
    mean, scale = x.mean(0), x.std(0) + 1e-9
    xn = (x - mean) / scale

    def loss(w):
        z = xn @ w
        z = z - np.maximum.reduceat(z, np.r_[0, np.cumsum([len(f) for f, _ in groups])[:-1]])[gi]
        e = np.exp(z)
        den = np.bincount(gi, e)
        num = np.bincount(gi, e * y)
        p = e / den[gi]
        grad = -(xn.T @ (y * 1.0 / num[gi] * e - p)) + 2 * l2 * w
        return -np.sum(np.log(num / den)) + l2 * w @ w, grad

    from scipy.optimize import minimize  # here: 0.4 s of every localizer start otherwise

    w = minimize(loss, np.zeros(x.shape[1]), jac=True, method="L-BFGS-B").x
    return Verifier(w, mean, scale)
