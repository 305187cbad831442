"""MSAC scoring of pose hypotheses, and their robust refinement.

Scoring: each query object costs the smallest normalised squared residual over its same-class
candidates, truncated at ``tau**2``, plus the prior costs. The compiled kernels
(:mod:`flatlandia.solver.kernels`) do the data term; :func:`padded_costs` is the plain numpy form they are
tested against. Refinement: robust Gauss-Newton on each hypothesis' matches, re-associated
``refine_rounds`` times.
"""

from __future__ import annotations

import numpy as np

from flatlandia import geo
from flatlandia.solver import kernels, noise
from flatlandia.solver.priors import Priors
from flatlandia.solver.problem import Problem


def data_cost(problem: Problem, t, theta, s):
    """Capped data cost (C,), inlier mask (C, M) and best candidate (C, M) per hypothesis."""
    t = np.ascontiguousarray(t, dtype=float).reshape(-1, 2)
    theta = np.ascontiguousarray(theta, dtype=float).ravel()
    tau2 = float(problem.cfg.tau**2)
    tx, ty = t[:, 0].copy(), t[:, 1].copy()
    if problem.metric:
        return kernels.score_metric(tx, ty, theta, problem.terms, problem.candidates, tau2)
    s = np.ascontiguousarray(s, dtype=float).ravel()
    return kernels.score_depth(tx, ty, theta, s, problem.terms, problem.candidates, tau2)


def score(problem: Problem, priors: Priors, t, theta, s):
    """MSAC cost (C,), inlier mask (C, M) and best candidate (C, M) per hypothesis."""
    return score_terms(problem, priors, t, theta, s)[1:]


def score_terms(problem: Problem, priors: Priors, t, theta, s):
    """Data cost (C,), MSAC cost with the priors (C,), inlier mask (C, M) and best candidate (C, M)."""
    data, inl, match = data_cost(problem, t, theta, s)
    nb = priors.neighbours(t)
    cost = data + priors.cost(t, s, theta, nb) + priors.covis_cost(t, inl, match, nb)
    if priors.fix is not None:
        cost = cost + priors.fix_cost(t, theta)
    return data, cost, inl, match


def padded_candidates(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """(M, K) same-class candidate indices padded to the largest class, and the mask of real ones."""
    sizes = np.array([len(s) for s in problem.same])
    kmax = max([*sizes.tolist(), 1])
    cand = np.zeros((problem.m, kmax), int)
    for k, s in enumerate(problem.same):
        cand[k, : len(s)] = s
    return cand, np.arange(kmax)[None] < sizes[:, None]


def padded_costs(problem: Problem, t: np.ndarray, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(C, M, K) normalised squared residuals of every query object vs its same-class candidates
    (the numpy reference of the compiled :func:`data_cost`)."""
    cfg, q = problem.cfg, problem.q
    cand, mask = padded_candidates(problem)
    cand_xy = problem.r[cand] if len(problem.r) else np.zeros(cand.shape + (2,))
    if problem.metric:
        rx = cand_xy[None, ..., 0] - t[:, 0, None, None]  # (C, M, K) world offsets of the candidates
        ry = cand_xy[None, ..., 1] - t[:, 1, None, None]
        c, sn = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
        lx = c * rx + sn * ry  # world -> camera frame
        ly = c * ry - sn * rx
        cost = ((lx - q[None, :, 0, None]) ** 2 + (ly - q[None, :, 1, None]) ** 2) / cfg.position_sigma_m**2
    else:
        # float32; the wrapped bearing error and both sigmas of the candidate's range bin (the noise
        # model); beyond the inlier cap costs are capped anyway, and objects behind the camera get inf
        f = np.float32
        rx = cand_xy[None, ..., 0].astype(f) - t[:, 0, None, None].astype(f)
        ry = cand_xy[None, ..., 1].astype(f) - t[:, 1, None, None].astype(f)
        wb = (theta[:, None] + problem.q_bear[None]).astype(f)  # (C, M) query directions in the world
        ux, uy = np.cos(wb)[..., None], np.sin(wb)[..., None]
        along = ux * rx + uy * ry
        across = ux * ry - uy * rx
        db = np.where(along > 0, np.arctan2(across, along), f(np.inf))
        rr = np.sqrt(rx * rx + ry * ry)
        edges, sb, sr = problem.msac_noise
        b = noise.bins(edges, rr)
        sc = s.astype(f)[:, None, None]
        q_range = (problem.q_range + problem.eps_q).astype(f)[None, :, None]
        dr = np.log((rr + sc * f(problem.eps_q)) / (sc * q_range))
        cost = (db / sb.astype(f)[b]) ** 2 + (dr / sr.astype(f)[b]) ** 2
    return np.where(mask[None], cost, np.inf)


def refine(
    problem: Problem,
    priors: Priors,
    t: np.ndarray,
    theta: np.ndarray,
    s: np.ndarray,
    iters: int = 15,
    rounds: int | None = None,
):
    """Robust Gauss-Newton with re-association for C hypotheses at once -> (t (C, 2), theta, s).

    Objective: bearing + weak log-range residuals (positions for metric maps) of the matched
    inliers, plus the priors for depth maps; soft-L1 weights (IRLS), analytic Jacobians, a little
    Levenberg damping; matches re-associated ``refine_rounds`` times.
    """
    p = np.column_stack([t, theta, np.log(np.maximum(s, 1e-9))]).astype(float)
    for _ in range(problem.cfg.refine_rounds if rounds is None else int(rounds)):
        _, inl, match = data_cost(problem, p[:, :2], p[:, 2], np.exp(p[:, 3]))
        matched = np.ascontiguousarray(problem.r[match])  # (C, M, 2)
        kernels.refine_gauss_newton(p, matched, inl, problem.refine_terms, priors.refine_terms(p), iters)
    scale = np.exp(p[:, 3]) if not problem.metric else np.ones(len(p))
    return p[:, :2].copy(), geo.wrap_angle(p[:, 2]), scale
