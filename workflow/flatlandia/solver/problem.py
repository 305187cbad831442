"""The data of one solver query: the local map, its candidates, and the kernels' views of them.

Why a class of its own: every step of the solver (hypotheses, scoring, refinement) reads the
same derived arrays (bearings, ranges, the same-class candidate lists); they are computed once.
"""

from __future__ import annotations

import numpy as np

from flatlandia.solver import likelihood_kernels
from flatlandia.solver.kernels import Candidates, QueryTerms
from flatlandia.solver.noise import NoiseModel


def msac_noise(cfg, noise: NoiseModel | None) -> NoiseModel:
    """The noise model the MSAC cost reads: the fitted one, or without one (no learned priors)
    the settings' constant model (``solver.default_bearing_sigma_deg``, ``default_log_range_sigma``)."""
    return (
        noise if noise is not None else NoiseModel.constant(cfg.default_bearing_sigma_deg, cfg.default_log_range_sigma)
    )


class Problem:
    """Query objects (camera frame) and candidate reference objects (metric frame) of one query;
    ``noise``: the depth maps' noise model (:mod:`flatlandia.solver.noise`; None: the settings'
    constant one)."""

    def __init__(self, q, q_cls, r, r_cls, metric: bool, cfg, noise: NoiseModel | None = None):
        self.q = np.asarray(q, float).reshape(-1, 2)
        self.qc = np.asarray(q_cls).astype(int).ravel()
        self.r = np.asarray(r, float).reshape(-1, 2)
        self.rc = np.asarray(r_cls).astype(int).ravel()
        self.metric = metric
        self.cfg = cfg
        self.m = len(self.q)
        self.q_bear = np.arctan2(self.q[:, 1], self.q[:, 0])
        self.q_range = np.linalg.norm(self.q, axis=1)
        #: per query object, the rows of ``r`` of its class
        self.same = [np.flatnonzero(self.rc == c) for c in self.qc]
        self.noise = msac_noise(cfg, noise)
        #: the MSAC cost's noise: the model's, ranges weighed ``msac_range_inflation`` times more loosely
        self.msac_noise = self.noise.terms(cfg.msac_range_inflation)
        # small-range guard (objects at the camera): log of (range + eps)
        self.eps_q = 0.02 * max(float(np.median(self.q_range)), 1e-9)
        self.rx, self.ry = self.r[:, 0].copy(), self.r[:, 1].copy()
        self.candidates = self._flat_candidates()
        self.terms = QueryTerms(
            metric,
            self.q[:, 0].copy(),
            self.q[:, 1].copy(),
            self.q_bear,
            self.q_range + self.eps_q,
            float(self.eps_q),
            *self.msac_noise,
            float(cfg.position_sigma_m),
        )
        #: the refinement weighs ranges ``refine_range_inflation`` times more weakly than the scoring
        self.refine_noise = self.msac_noise._replace(
            log_range_sigma=self.msac_noise.log_range_sigma * float(cfg.refine_range_inflation)
        )
        self.refine_terms = self.terms._replace(log_range_sigma=self.refine_noise.log_range_sigma)
        self._density: tuple[float, np.ndarray] | None = None

    def log_density(self, radius_m: float) -> np.ndarray:
        """(N,) log density (per m^2) of each candidate's class within ``radius_m`` of it (computed
        once per radius): the chance of an object of that class lying there at random."""
        if self._density is None or self._density[0] != float(radius_m):
            rc = self.rc.astype(np.int64)
            self._density = (float(radius_m), likelihood_kernels.class_density(self.rx, self.ry, rc, float(radius_m)))
        return self._density[1]

    def _flat_candidates(self) -> Candidates:
        """The same-class candidates without padding, as the compiled kernels walk them."""
        ptr = np.r_[0, np.cumsum([len(s) for s in self.same])].astype(np.int64)
        idx = np.concatenate(self.same + [np.zeros(0, int)]).astype(np.int64)
        xy = self.r[idx] if len(idx) else np.zeros((0, 2))
        return Candidates(xy[:, 0].copy(), xy[:, 1].copy(), idx, ptr)

    def solvable(self) -> bool:
        """At least two query objects and two candidates: a pose can be hypothesised."""
        return self.m >= 2 and len(self.r) >= 2
