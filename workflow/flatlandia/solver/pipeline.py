"""Geometric 3DoF solver: pose of a camera from a local object map and a reference object map.

No training of the geometry (a verifier of depth-map hypotheses may be learned from the training
split, step 4). Given the query's local map (camera at the origin looking along +x, +y left), the
classes of its objects (known) and candidate reference objects (a region proposal or the whole
map, metric frame), find (x, y, theta) such that the query objects land on same-class reference
objects.

Two kinds of local map:

- ``metric=True`` (GT local maps, metres): a rigid copy of the reference; hypotheses are 2-point
  rigid fits of a same-class pair whose lengths agree, residuals are positions in metres.
- ``metric=False`` (depth local maps, unknown per-query scale): bearings are accurate (median
  error about 0.5 deg) while ranges are noisy (factor 0.6-2 after the best scale) and unscaled,
  so each hypothesis carries its own scale ``s`` (metres per local unit) and residuals are the
  bearing (weight 1/sigma_b) and the log-range (weight 1/sigma_r, much weaker).

Steps: (1) hypotheses from pairs of query objects x same-class ordered pairs of candidate
objects (2-point similarity: position, heading, scale), optionally kept only near a prior
(training-split cameras) and within a plausible scale; on depth maps, a region of more than
``covis_gate_above`` candidates hypothesises only from candidate pairs and triples that a
training camera saw together (the co-visibility gate: a whole-map query scores about a thousand
hypotheses instead of up to 300,000); (2) MSAC scoring: each query
object costs the smallest normalised squared residual over same-class candidates, truncated at
``tau**2``, plus prior costs (distance [and heading difference] to the nearest training camera,
log-scale for depth maps, co-visibility) when priors are given; (3) the ``top_k`` distinct
hypotheses are refined (robust Gauss-Newton on their matches, with re-association), re-scored,
and the cheapest wins; (4) or, given a verifier (depth maps with priors), the ``verify_top_k``
best are refined and the verifier's highest score wins (:mod:`flatlandia.solver.verify`: near-tie hypotheses
that the cost ranks wrongly, told apart by what the training cameras near each pose saw). The
next-best distinct poses of the same pool come along as alternatives (:func:`locate`, which
:func:`solve` and every caller go through). The inner loops (hypotheses, scoring, refinement) are compiled with numba in
``kernels``; ``scoring.padded_costs`` keeps the padded numpy form as the reference
they are tested against. For depth maps hypotheses come from 3-bearing resections (range-free)
and then 2-point similarities. The result holds the pose, the inlier matches (query index,
candidate index) and a confidence in [0, 1].

Where each step lives (modules of :mod:`flatlandia.solver`): ``problem`` (the query's derived
arrays), ``noise`` (the one noise model), ``priors`` (the training-split priors), ``hypotheses``
(generation, gating, chunked scoring, the distinct best), ``camera_hypotheses`` (the seeds at every
training camera), ``scoring`` (MSAC cost and refinement), ``verify`` (the verifier's features and
score) and ``verify_fit`` (learning it), ``likelihood`` and ``calibration`` (the answer's
probability), ``kernels`` (the compiled loops); ``bound`` refines on the true matches (the bound
the choice of hypotheses is held to).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from flatlandia.solver import calibration, camera_hypotheses, distortion, hypotheses, likelihood, scoring, verify
from flatlandia.solver.priors import Fix, Priors, TrainingPriors
from flatlandia.solver.problem import Problem
from flatlandia.solver.settings import SolverConfig
from flatlandia.solver.verify import Verifier


@dataclass
class Solution:
    x: float
    y: float
    theta: float  # radians, CCW from east
    scale: float  # metres per local unit (1 for metric maps)
    inliers: list[tuple[int, int]] = field(default_factory=list)  # (query index, candidate index)
    confidence: float = 0.0
    cost: float = float("inf")  # MSAC cost of the returned pose
    n_hypotheses: int = 0
    behind: float = 0.0  # how far the ranking puts it behind the best (0 for the best), a log-likelihood ratio
    probability: float = float("nan")  # P(within (5 m, 5 deg)): the pool's share of this place, calibrated
    llr: float | None = None  # the likelihood ratio against chance (None: no model)
    share: float | None = None  # the pool's share of its place, before the calibration
    #: log of the evidence of this place and of the whole pool (:func:`calibration.log_evidence`):
    #: what the null hypothesis' key is fitted on
    log_place: float | None = None
    log_pool: float | None = None
    agreement: float | None = None  # a sequence's: the share of frames whose own answer is this place


#: alternatives are poses at least this far (metres) or this many degrees from the best and from
#: each other (a refined pool may hold the same pose twice: two hypotheses that converged)
DISTINCT_M = 2.0
DISTINCT_DEG = 5.0


@dataclass
class Localization:
    """One query's answer from one pool of refined hypotheses: the best pose (None: none) and the
    next-best distinct poses, best first."""

    best: Solution | None
    alternatives: list[Solution] = field(default_factory=list)


def solve(
    query_xy,
    query_cls,
    ref_xy,
    ref_cls,
    metric: bool = False,
    config: SolverConfig | dict | None = None,
    priors: TrainingPriors | None = None,
    fix: Fix | None = None,
) -> Solution | None:
    """Camera pose in the reference frame, or None when no hypothesis can be formed.

    ``query_xy``: (M, 2) local map; ``query_cls``: (M,) classes; ``ref_xy``/``ref_cls``: the
    candidate reference objects (metric frame); ``metric``: True for GT (metre) local maps,
    False for unscaled depth maps; ``priors`` (:class:`~flatlandia.solver.priors.TrainingPriors`,
    its ``seen`` over the rows of ``ref_xy``): the training cameras (hypotheses farther than
    ``prior_radius_m`` from every one are dropped, the distance to the nearest, and with headings
    ``prior_heading_sigma_deg`` > 0 the heading difference, is a soft cost), what they saw (the
    co-visibility cost ``covis_weight`` and gate ``covis_gate_above``), the depth maps' log-scale
    prior, and a verifier that picks among the ``verify_top_k`` best hypotheses of a depth map
    (``verify``; needs cameras and what they saw), else the cheapest of the ``top_k`` best wins.
    Inlier indices refer to rows of ``ref_xy``. ``fix`` (:class:`~flatlandia.solver.priors.Fix`): a
    position fix of the camera (GPS) and optionally a compass heading, as a likelihood (a gate at
    ``Fix.GATE_SIGMAS`` sigmas and a cost; None: none). The best pose of :func:`locate`.
    """
    return locate(query_xy, query_cls, ref_xy, ref_cls, metric, config, priors, fix=fix).best


def locate(
    query_xy,
    query_cls,
    ref_xy,
    ref_cls,
    metric: bool = False,
    config: SolverConfig | dict | None = None,
    priors: TrainingPriors | None = None,
    alternatives: int = 0,
    fix: Fix | None = None,
) -> Localization:
    """The best pose (:func:`solve`'s, arguments as there) and up to ``alternatives`` next-best
    distinct poses from the same pool of refined hypotheses (the ``top_k``, or with a verifier the
    ``verify_top_k``, best), in the order that chose the best: the cost, or the verifier's score.
    Alternatives are at least :data:`DISTINCT_M` metres or :data:`DISTINCT_DEG` degrees from the
    best and from each other; each carries its inliers, its cost, the share of the query's objects
    it explains as its confidence, ``behind``: how far the ranking puts it behind the best, and its
    ``probability`` of being within (5 m, 5 deg) (:func:`ranking_key`, :mod:`calibration`). The one
    entry point of the fine stage's runs, the city search and ``flatlandia localize``. With a
    ``fix`` the verifier's score is added the fix's log-likelihood (-cost / 2)."""
    verifier = priors.verifier if priors is not None else None
    pool = candidates(query_xy, query_cls, ref_xy, ref_cls, metric, config, priors, verifier is not None, fix)
    return Localization(None) if pool is None else _ranked(pool, verifier, alternatives)


@dataclass
class Pool:
    """The refined distinct best hypotheses of one query, with what scored them."""

    problem: Problem
    priors: Priors
    t: np.ndarray  # (C, 2)
    theta: np.ndarray  # (C,)
    s: np.ndarray  # (C,)
    n_hypotheses: int
    verified: bool  # a verifier chooses among them


def candidates(
    query_xy,
    query_cls,
    ref_xy,
    ref_cls,
    metric: bool = False,
    config: SolverConfig | dict | None = None,
    priors: TrainingPriors | None = None,
    use_verifier: bool = False,
    fix: Fix | None = None,
) -> Pool | None:
    """The refined distinct best hypotheses (arguments as :func:`solve`): ``verify_top_k`` of them
    when a verifier will choose (``use_verifier``) and can, else ``top_k``."""
    cfg = config if isinstance(config, SolverConfig) else SolverConfig.from_dict(config)
    if not metric and priors is not None and priors.bearing_k:  # the scene's lens, undone before matching
        query_xy = distortion.undistort(query_xy, priors.bearing_k)
    problem = Problem(query_xy, query_cls, ref_xy, ref_cls, metric, cfg, priors.noise if priors is not None else None)
    query_priors = Priors(cfg, metric, priors, n_ref=len(problem.r), fix=fix)
    if not problem.solvable():
        return None
    verified = use_verifier and verify.usable(problem, query_priors)
    keep = cfg.verify_top_k if verified else cfg.top_k
    scored = hypotheses.score_hypotheses(problem, query_priors, keep)
    kept = scored.arrays()
    seeded = camera_hypotheses.seeds(problem, query_priors) if verified else None
    if kept is None and seeded is None:
        return None
    n_hyp = scored.n_hypotheses
    t, theta, s = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    if kept is not None:
        cost, t, theta, s = kept
        chosen = hypotheses.distinct_best(cost, t, theta, keep)
        t, theta, s = scoring.refine(problem, query_priors, t[chosen], theta[chosen], s[chosen])
    if seeded is not None:  # the complete set: every camera's seed beside the cost-picked pool
        n_hyp += seeded[3]
        t, theta, s = (np.concatenate([a, b]) for a, b in zip((t, theta, s), seeded[:3]))
        merged = scoring.score(problem, query_priors, t, theta, s)[0]
        merged = np.where(np.isfinite(t).all(1), merged, np.inf)
        chosen = hypotheses.distinct_best(merged, t, theta, cfg.pool_max or len(merged))
        t, theta, s = t[chosen], theta[chosen], s[chosen]
    return Pool(problem, query_priors, t, theta, s, n_hyp, verified)


def ranking_key(problem: Problem, priors: Priors, key: np.ndarray, t, theta, s) -> tuple[np.ndarray, np.ndarray]:
    """(key, likelihood ratio) of refined poses: a ranking ``key`` (a negative log-odds: the cost
    halved, or minus the verifier's score) less ``likelihood_weight`` times the likelihood ratio
    against chance (:mod:`flatlandia.solver.likelihood`) when the priors carry its model (depth
    maps); the ratio is nan without one."""
    w = float(problem.cfg.likelihood_weight)
    if priors.likelihood is None or w <= 0 or problem.metric:
        return key, np.full(len(key), np.nan)
    llr = likelihood.pose_llr(problem, priors, priors.likelihood, problem.cfg.density_radius_m, t, theta, s)[0]
    return key - w * llr, llr


def _ranked(pool: Pool, verifier: Verifier | None, alternatives: int = 0) -> Localization:
    """The best refined pose that stayed finite and near the prior cameras (the lowest key: the
    cost, or the verifier's score, with the likelihood ratio, :func:`ranking_key`), with its
    inliers, a confidence (the share of explained objects, lowered when a distinct pose is nearly
    as good: a log-likelihood ratio) and its probability (the pool's share of its place,
    calibrated); and up to ``alternatives`` next-best distinct poses (:func:`locate`)."""
    problem, priors, t, theta, s = pool.problem, pool.priors, pool.t, pool.theta, pool.s
    data, cost, inl, match = scoring.score_terms(problem, priors, t, theta, s)
    finite = np.isfinite(t).all(1)
    far = np.ones(len(t), bool)
    far[finite] = priors.drifted(t[finite])
    ok = np.flatnonzero(finite & ~far).tolist()
    if not ok:
        return Localization(None)
    if pool.verified:
        key = -verifier.score(verify.features(problem, priors, t, theta, s, data, inl, match))
        if priors.fix is not None:  # the fix's log-likelihood beside the verifier's log-odds
            key = key + priors.fix_cost(t, theta) / 2.0
    else:
        key = cost / 2.0
    key, llr = ranking_key(problem, priors, key, t, theta, s)
    ok_mask = np.zeros(len(t), bool)
    ok_mask[ok] = True
    log_place, log_pool = calibration.log_evidence(t, theta, key, ok_mask)
    null_key = priors.calibration.null_key if priors.calibration is not None else None
    share = calibration.null_share(log_place, log_pool, null_key)
    prob = calibration.probability(priors.calibration, share, problem.m, 1)
    ok.sort(key=lambda k: float(key[k]))
    best = ok[0]

    def inliers(k: int) -> list[tuple[int, int]]:
        return [(int(j), int(match[k, j])) for j in range(problem.m) if inl[k, j]]

    def solution(k: int, confidence: float) -> Solution:
        return Solution(
            float(t[k, 0]),
            float(t[k, 1]),
            float(theta[k]),
            float(s[k]),
            inliers(k),
            float(confidence),
            float(cost[k]),
            pool.n_hypotheses,
            float(key[k]) - float(key[best]),
            float(prob[k]),
            float(llr[k]) if np.isfinite(llr[k]) else None,
            float(share[k]),
            log_place=float(log_place[k]),
            log_pool=float(log_pool),
        )

    conf = len(inliers(best)) / problem.m
    for other in ok[1:]:
        if np.hypot(*(t[other] - t[best])) > 2.0:
            conf *= float(1 - np.exp(-(float(key[other]) - float(key[best]))))
            break
    chosen = [best]
    for other in ok[1:]:
        if len(chosen) > alternatives:
            break
        if all(_distinct(t[other], theta[other], t[c], theta[c]) for c in chosen):
            chosen.append(other)
    return Localization(
        solution(best, conf),
        [solution(k, len(inliers(k)) / problem.m) for k in chosen[1:]],
    )


def _distinct(t_a, theta_a, t_b, theta_b) -> bool:
    """Two poses at least :data:`DISTINCT_M` metres or :data:`DISTINCT_DEG` degrees apart."""
    turn = abs((float(theta_a) - float(theta_b) + np.pi) % (2 * np.pi) - np.pi)
    return bool(np.hypot(*(t_a - t_b)) >= DISTINCT_M or turn >= np.radians(DISTINCT_DEG))


@functools.cache
def warm_up() -> None:
    """Compile (or load from numba's cache) every solver kernel on a tiny problem, so that timed
    queries never include compilation (seconds the first time in a process without a cache):
    metric and depth maps, the seeds and the verifier's pool, the likelihood ratio. Once per
    process (cached): every scene's evaluation calls it."""
    from flatlandia import classes

    rng = np.random.default_rng(0)
    ref, ref_cls = rng.uniform(-50, 50, (30, 2)), rng.integers(0, 3, 30)
    q, q_cls = rng.uniform(1, 20, (5, 2)), ref_cls[:5]
    prior, seen = rng.uniform(-50, 50, (20, 3)), rng.random((20, 30)) < 0.3
    nf, nb = len(verify.FEATURES), len(likelihood.RANGE_EDGES_M) - 1
    na, nk = len(likelihood.BEARING_EDGES_DEG) - 1, classes.N_CLASSES
    zeros = (0.0,) * nk, (0.0,) * nb, (0.0,) * na
    flat = likelihood.LikelihoodModel(50.0, 80.0, -1.0, *zeros, 0.0, 0.0, -1.0, *zeros)
    verifier = Verifier(np.zeros(nf), np.zeros(nf), np.ones(nf))
    for metric in (True, False):
        solve(
            q,
            q_cls,
            ref,
            ref_cls,
            metric=metric,
            config={"covis_weight": 1.0, "prior_heading_sigma_deg": 20.0},
            priors=TrainingPriors(prior, seen, (2.0, 0.5), verifier, flat),
        )
