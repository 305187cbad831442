"""The geometric solver: a camera's 3DoF pose from the objects one image sees and an object map.

A stage of its own, used by the fine stage (rule fine_eval), the coarse stage (its training-free
proposals, rule coarse_solver), the city search and the images scenes' localization. Its settings
are the config section ``solver``; its learned priors (the depth maps' scale prior, the verifier)
are fitted once per benchmark by rule solver_priors.

Modules, in the order a query meets them: ``distortion`` (the scene's radial bearing correction of
depth maps), ``problem`` (the query's derived arrays), ``priors`` (what the training split tells
about a pose), ``hypotheses`` (generation, gating, chunked scoring, the distinct best),
``camera_hypotheses`` (a hypothesis seeded at every training camera: the complete pool),
``scoring`` (MSAC cost, refinement), ``verify`` (the verifier's
features and score) and ``verify_fit`` (learning it), ``likelihood`` (a pose scored against chance,
missed objects counted; its compiled loop in ``likelihood_kernels``), ``calibration`` (a pool's
log-odds as the probability of an answer, beside a null hypothesis) and ``calibration_fit``
(fitting it on the validation split and on ``nonsense`` queries that fit no place), ``regions``
(the answers of several regions of one map combined), ``kernels`` (the compiled loops),
``pipeline`` (the steps in order: :func:`locate`, the best pose and its alternatives, and
:func:`solve`, the best alone), ``sequence`` (several frames tied by relative poses, localized
together: :func:`locate_sequence`; its compiled loops in ``sequence_kernels``), ``learned_priors`` (the fitted priors as one value,
read and written as JSON), ``bound`` (the pose given the true matches).
"""

from flatlandia.solver.learned_priors import LearnedPriors, scene_priors, with_learned
from flatlandia.solver.pipeline import Localization, Solution, SolverConfig, candidates, locate, solve, warm_up
from flatlandia.solver.priors import Fix, TrainingPriors, depth_scale_prior, fit_scale
from flatlandia.solver.sequence import SequenceConfig, SequenceLocalization, locate_sequence

__all__ = [
    "Fix",
    "LearnedPriors",
    "Localization",
    "Solution",
    "SequenceConfig",
    "SequenceLocalization",
    "SolverConfig",
    "TrainingPriors",
    "candidates",
    "depth_scale_prior",
    "fit_scale",
    "locate",
    "locate_sequence",
    "scene_priors",
    "solve",
    "warm_up",
    "with_learned",
]
