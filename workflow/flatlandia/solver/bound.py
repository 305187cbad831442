"""What the geometry allows: the pose of a depth local map given its true matches.

Why: the solver's loss splits into choosing the wrong matches and the noise of the right ones.
Refining the pose on the true matches, from the true pose (so the nearest optimum of the robust
cost), measures the second part alone: the bound the solver's choice of hypotheses is held to.
The bound depends on the evidence used: bearings only (the range-free geometry), bearings and
ranges, and with the training-split priors (camera positions and headings, scale) as well.
"""

from __future__ import annotations

import numpy as np

from flatlandia.solver import kernels, pipeline
from flatlandia.solver.priors import Priors, TrainingPriors
from flatlandia.solver.problem import Problem

#: the evidence of each bound: (range terms, priors); without range terms the range weight is nil
EVIDENCE = {
    "bearings": (False, False),
    "bearings + ranges": (True, False),
    "bearings + ranges + priors": (True, True),
}
#: Gauss-Newton iterations (one association: the matches are given)
ITERATIONS = 50


def true_match_pose(
    depth_xy,
    matched_xy,
    start,
    ranges: bool,
    config: pipeline.SolverConfig | dict | None = None,
    given: TrainingPriors | None = None,
) -> tuple[float, float, float]:
    """(x, y, heading in radians) of a depth local map whose object k is the reference object at
    ``matched_xy[k]``: robust Gauss-Newton (the solver's refinement) from ``start`` = (x, y,
    heading, metres per local unit), on bearings, plus log-ranges when ``ranges``, plus the camera
    and scale priors of ``given`` (its co-visibility is not used: the matches are given)."""
    cfg = config if isinstance(config, pipeline.SolverConfig) else pipeline.SolverConfig.from_dict(config)
    if not ranges:  # bearings only: a vanishing range weight
        cfg = pipeline.SolverConfig(**{**cfg.to_dict(), "refine_range_inflation": 1e6})
    m = len(depth_xy)
    given = given or TrainingPriors()
    problem = Problem(depth_xy, np.zeros(m, int), matched_xy, np.zeros(m, int), False, cfg, given.noise)
    priors = Priors(cfg, False, TrainingPriors(given.cameras, None, given.scale))
    x, y, theta, scale = start
    p = np.array([[x, y, theta, np.log(scale)]], float)
    matched = np.ascontiguousarray(np.asarray(matched_xy, float).reshape(1, m, 2))
    inl = np.ones((1, m), bool)
    kernels.refine_gauss_newton(p, matched, inl, problem.refine_terms, priors.refine_terms(p), ITERATIONS)
    return float(p[0, 0]), float(p[0, 1]), float(p[0, 2])
