"""Geometric 3DoF solver: pose of a camera from a local object map and a reference object map.

No training. Given the query's local map (camera at the origin looking along +x, +y left), the
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
(training-split cameras) and within a plausible scale; (2) MSAC scoring: each query
object costs the smallest normalised squared residual over same-class candidates, truncated at
``tau**2``, plus prior costs (distance [and heading difference] to the nearest training camera,
log-scale for depth maps, co-visibility) when priors are given; (3) the ``top_k`` distinct
hypotheses are refined (robust Gauss-Newton on their matches, with re-association), re-scored,
and the best wins. The inner loops (hypotheses, scoring, refinement) are compiled with numba in
``solver_kernels``; ``_Problem.costs`` keeps the padded numpy form as the reference they are
tested against. For depth maps hypotheses come from 3-bearing resections (range-free) and then
2-point similarities. The result holds
the pose, the inlier matches (query index, candidate index) and a confidence in [0, 1].
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from flatlandia import config, geo
from flatlandia.fine import solver_kernels

#: Defaults of the solver: the `fine.geo` section of workflow/schemas/config.schema.yaml.
_GEO = config.section_defaults("fine.geo")


@dataclass
class SolverConfig:
    """The solver's settings; each is described in config/README.md (`fine.geo.*`)."""

    bearing_sigma_deg: float = _GEO["bearing_sigma_deg"]
    log_range_sigma: float = _GEO["log_range_sigma"]
    refine_log_range_sigma: float = _GEO["refine_log_range_sigma"]
    position_sigma_m: float = _GEO["position_sigma_m"]
    tau: float = _GEO["tau"]
    max_pairs: int = _GEO["max_pairs"]
    max_triples: int = _GEO["max_triples"]
    max_triple_hyp: int = _GEO["max_triple_hyp"]
    max_hyp: int = _GEO["max_hyp"]
    top_k: int = _GEO["top_k"]
    refine_rounds: int = _GEO["refine_rounds"]
    min_scale: float = _GEO["min_scale"]
    max_scale: float = _GEO["max_scale"]
    prior_radius_m: float = _GEO["prior_radius_m"]
    prior_sigma_m: float = _GEO["prior_sigma_m"]
    prior_weight: float = _GEO["prior_weight"]
    prior_heading_sigma_deg: float = _GEO["prior_heading_sigma_deg"]
    prior_knn: int = _GEO["prior_knn"]
    scale_prior_weight: float = _GEO["scale_prior_weight"]
    covis_weight: float = _GEO["covis_weight"]
    covis_radius_m: float = _GEO["covis_radius_m"]
    covis_metric: bool = _GEO["covis_metric"]
    pair_len_tol_m: float = _GEO["pair_len_tol_m"]
    chunk: int = _GEO["chunk"]
    early_stop: bool = _GEO["early_stop"]

    @classmethod
    def from_dict(cls, d: dict | None) -> SolverConfig:
        """Strict: a key that is not a solver setting raises, naming the closest one."""
        return config.from_section(cls, "fine.geo", d)

    def to_dict(self) -> dict:
        return asdict(self)


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


class _Problem:
    """Query, candidates and the same-class candidate lists as a padded (M, K) index matrix."""

    def __init__(self, q, q_cls, r, r_cls, metric: bool, cfg: SolverConfig, prior=None, scale_prior=None):
        self.prior = prior  # cKDTree of plausible camera positions, or None
        self.prior_heading = None  # headings (rad) of the prior cameras, or None
        self.scale_prior = scale_prior  # (mean, std) of log(metres per local unit), or None
        self.seen = None  # (P, N) bool: prior camera p saw candidate n (training split), or None
        self.q = np.asarray(q, float).reshape(-1, 2)
        self.qc = np.asarray(q_cls).astype(int).ravel()
        self.r = np.asarray(r, float).reshape(-1, 2)
        self.rc = np.asarray(r_cls).astype(int).ravel()
        self.metric = metric
        self.cfg = cfg
        self.m = len(self.q)
        self.q_bear = np.arctan2(self.q[:, 1], self.q[:, 0])
        self.q_range = np.linalg.norm(self.q, axis=1)
        self.same = [np.flatnonzero(self.rc == c) for c in self.qc]
        self.sb = np.radians(cfg.bearing_sigma_deg)
        # small-range guards (objects at the camera): log of (range + eps)
        self.eps_q = 0.02 * max(float(np.median(self.q_range)), 1e-9)
        self.rx, self.ry = self.r[:, 0].copy(), self.r[:, 1].copy()
        # the same candidates flat (no padding) for the compiled scoring
        self.ptr = np.r_[0, np.cumsum([len(s) for s in self.same])].astype(np.int64)
        self.flat_idx = np.concatenate(self.same + [np.zeros(0, int)]).astype(np.int64)
        flat_xy = self.r[self.flat_idx] if len(self.flat_idx) else np.zeros((0, 2))
        self.flat_x, self.flat_y = flat_xy[:, 0].copy(), flat_xy[:, 1].copy()

    # ------------------------------------------------------------------ costs
    @functools.cached_property
    def cand(self) -> np.ndarray:
        """(M, K) same-class candidate indices, padded to the largest class (the numpy reference
        layout of :meth:`costs`; built on first use only: the compiled scoring uses the flat one)."""
        kmax = max([len(s) for s in self.same] + [1])
        cand = np.zeros((self.m, kmax), int)
        for k, s in enumerate(self.same):
            cand[k, : len(s)] = s
        return cand

    @functools.cached_property
    def cmask(self) -> np.ndarray:
        """(M, K) True on the real entries of :attr:`cand`."""
        return np.arange(self.cand.shape[1])[None] < np.array([len(s) for s in self.same])[:, None]

    def costs(self, t: np.ndarray, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(C, M, K) normalised squared residuals of every query object vs its same-class candidates
        (padded numpy form: the reference the compiled :meth:`data_cost` is tested against)."""
        cand_xy = self.r[self.cand] if len(self.r) else np.zeros(self.cand.shape + (2,))
        if self.metric:
            rx = cand_xy[None, ..., 0] - t[:, 0, None, None]  # (C, M, K) world offsets of the candidates
            ry = cand_xy[None, ..., 1] - t[:, 1, None, None]
            c, sn = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
            lx = c * rx + sn * ry  # world -> camera frame
            ly = c * ry - sn * rx
            d2 = (lx - self.q[None, :, 0, None]) ** 2 + (ly - self.q[None, :, 1, None]) ** 2
            cost = d2 / self.cfg.position_sigma_m**2
        else:
            # float32 and a tangent for the bearing error: about 4x faster than float64 arctan2 on the
            # (C, M, K) arrays. tan(db) equals db to 0.1 % within the inlier cap (tau sigmas, a few
            # degrees); beyond it costs are capped anyway, and objects behind the camera get inf.
            f = np.float32
            rx = cand_xy[None, ..., 0].astype(f) - t[:, 0, None, None].astype(f)
            ry = cand_xy[None, ..., 1].astype(f) - t[:, 1, None, None].astype(f)
            wb = (theta[:, None] + self.q_bear[None]).astype(f)  # (C, M) query directions in the world
            ux, uy = np.cos(wb)[..., None], np.sin(wb)[..., None]
            along = ux * rx + uy * ry
            across = ux * ry - uy * rx
            with np.errstate(divide="ignore", invalid="ignore"):
                tan_db = np.where(along > 0, across / along, f(np.inf))
            rr = np.sqrt(rx * rx + ry * ry)
            sc = s.astype(f)[:, None, None]
            dr = np.log((rr + sc * f(self.eps_q)) / (sc * (self.q_range + self.eps_q).astype(f)[None, :, None]))
            cost = (tan_db / f(self.sb)) ** 2 + (dr / f(self.cfg.log_range_sigma)) ** 2
        return np.where(self.cmask[None], cost, np.inf)

    def _prior_neighbours(self, t):
        """Distances and indices (C, k) of the ``prior_knn`` nearest prior cameras (k = 1 when
        neither the heading prior nor co-visibility needs more): one tree query for both."""
        cfg = self.cfg
        need = (self.prior_heading is not None and cfg.prior_heading_sigma_deg > 0) or self._covis_on()
        k = min(cfg.prior_knn, self.prior.n) if need else 1
        # farther cameras change nothing: their prior cost is capped and co-visibility ignores them
        bound = max(cfg.tau * cfg.prior_sigma_m, cfg.covis_radius_m if self._covis_on() else 0.0) + 1e-9
        d, j = self.prior.query(t, k=k, distance_upper_bound=bound)
        return d.reshape(len(t), k), np.minimum(j, self.prior.n - 1).reshape(len(t), k)  # missing: d = inf

    def _covis_on(self) -> bool:
        cfg = self.cfg
        return (
            self.seen is not None
            and cfg.covis_weight > 0
            and self.prior is not None
            and (not self.metric or cfg.covis_metric)
        )

    def _pose_prior_sq(self, t, theta, nb=None) -> np.ndarray:
        """(C,) squared normalised distance of poses to the prior cameras (position [+ heading])."""
        cfg = self.cfg
        d, j = nb if nb is not None else self._prior_neighbours(t)
        if self.prior_heading is None or cfg.prior_heading_sigma_deg <= 0:
            return (d[:, 0] / cfg.prior_sigma_m) ** 2
        dth = geo.wrap_angle(self.prior_heading[j] - np.asarray(theta).reshape(-1, 1))
        return np.min((d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, axis=1)

    def prior_cost(self, t, s, theta=None, nb=None) -> np.ndarray:
        """(C,) prior cost: pose vs the nearest prior camera, log-scale; each capped at tau^2."""
        tau2 = self.cfg.tau**2
        out = np.zeros(len(t))
        if self.prior is not None and self.cfg.prior_weight > 0:
            out += self.cfg.prior_weight * np.minimum(self._pose_prior_sq(t, theta, nb), tau2)
        if not self.metric and self.scale_prior is not None and self.cfg.scale_prior_weight > 0:
            mu, sd = self.scale_prior
            out += self.cfg.scale_prior_weight * np.minimum(((np.log(s) - mu) / sd) ** 2, tau2)
        return out

    def covis_cost(self, t, inl, match, nb=None) -> np.ndarray:
        """(C,) co-visibility cost: ``covis_weight`` per inlier whose candidate no prior camera within
        ``covis_radius_m`` of the pose saw together with the most of the others (best single camera)."""
        if not self._covis_on():
            return np.zeros(len(t))
        d, j = nb if nb is not None else self._prior_neighbours(t)
        cnt = solver_kernels.covis_counts(
            np.ascontiguousarray(d),
            np.ascontiguousarray(j, dtype=np.int64),
            self.seen,
            match,
            inl,
            float(self.cfg.covis_radius_m),
        )
        return self.cfg.covis_weight * (inl.sum(1) - cnt)

    def data_cost(self, t, theta, s):
        """Capped data cost (C,), inlier mask (C, M) and best candidate (C, M): compiled loops
        (``solver_kernels``), equal to the padded numpy :meth:`costs` reduced per object."""
        t = np.ascontiguousarray(t, dtype=float).reshape(-1, 2)
        theta = np.ascontiguousarray(theta, dtype=float).ravel()
        tau2 = float(self.cfg.tau**2)
        if self.metric:
            return solver_kernels.score_metric(
                t[:, 0].copy(),
                t[:, 1].copy(),
                theta,
                self.q[:, 0].copy(),
                self.q[:, 1].copy(),
                self.flat_x,
                self.flat_y,
                self.flat_idx,
                self.ptr,
                float(self.cfg.position_sigma_m),
                tau2,
            )
        return solver_kernels.score_depth(
            t[:, 0].copy(),
            t[:, 1].copy(),
            theta,
            np.ascontiguousarray(s, dtype=float).ravel(),
            self.q_bear,
            self.q_range + self.eps_q,
            float(self.eps_q),
            self.flat_x,
            self.flat_y,
            self.flat_idx,
            self.ptr,
            float(self.sb),
            float(self.cfg.log_range_sigma),
            tau2,
        )

    def score(self, t, theta, s):
        """MSAC cost (C,), inlier mask (C, M) and best candidate (C, M) per hypothesis."""
        total, inl, match = self.data_cost(t, theta, s)
        nb = self._prior_neighbours(np.asarray(t, float).reshape(-1, 2)) if self.prior is not None else None
        total = total + self.prior_cost(t, s, theta, nb) + self.covis_cost(t, inl, match, nb)
        return total, inl, match

    # ------------------------------------------------------------------ hypotheses
    def pair_hypotheses(self, i: int, j: int):
        """2-point fits of query objects (i, j) onto every same-class ordered candidate pair (a, b)."""
        a, b = self.same[i], self.same[j]
        if not len(a) or not len(b):
            return None
        dq = self.q[j] - self.q[i]
        if float(np.hypot(*dq)) < 1e-9:
            return None
        return solver_kernels.pair_fits(
            a.astype(np.int64),
            b.astype(np.int64),
            self.rx,
            self.ry,
            float(self.q[i, 0]),
            float(self.q[i, 1]),
            float(dq[0]),
            float(dq[1]),
            self.metric,
            float(self.cfg.pair_len_tol_m),
            float(self.cfg.min_scale),
            float(self.cfg.max_scale),
        )

    def triple_hypotheses(self, i: int, j: int, k: int, limit: int):
        """3-bearing resections (range-free) of query objects (i, j, k) onto same-class candidate triples.

        With u = 1 / (A - z) (complex, z the camera), the bearing condition
        arg((P - z) / (A - z)) = beta_P - beta_A reads Im(e^{-i alpha} ((P - A) u + 1)) = 0, linear
        in u; the two conditions for P = B, C fix u and so z; theta follows from A.
        """
        ca, cb, cc = self.same[i], self.same[j], self.same[k]
        if min(len(ca), len(cb), len(cc)) == 0 or len(ca) * len(cb) * len(cc) > limit:
            return None
        qb, qr = self.q_bear, self.q_range
        return solver_kernels.triple_resections(
            ca.astype(np.int64),
            cb.astype(np.int64),
            cc.astype(np.int64),
            self.rx,
            self.ry,
            float(qb[i]),
            float(qb[j]),
            float(qb[k]),
            float(qr[i]),
            float(qr[j]),
            float(qr[k]),
            float(self.eps_q),
            float(self.cfg.min_scale),
            float(self.cfg.max_scale),
            self.metric,
        )

    def query_triples(self) -> list[tuple[int, int, int]]:
        m = self.m
        tr = [(i, j, k) for i in range(m) for j in range(i + 1, m) for k in range(j + 1, m)]
        key = []
        for i, j, k in tr:
            b = np.sort(self.q_bear[[i, j, k]])
            sep = min(b[1] - b[0], b[2] - b[1])  # the smaller gap conditions the resection
            n = len(self.same[i]) * len(self.same[j]) * len(self.same[k])
            key.append(-min(sep, np.radians(30.0)) / (1 + n) ** (1 / 3))
        order = np.argsort(key, kind="stable")
        return [tr[o] for o in order]

    def query_pairs(self) -> list[tuple[int, int]]:
        m = self.m
        pairs = [
            (i, j)
            for i in range(m)
            for j in range(i + 1, m)
            if np.hypot(*(self.q[j] - self.q[i])) > 1e-9 and len(self.same[i]) and len(self.same[j])
        ]
        if self.metric:  # longest pairs first (best conditioned); rarer classes first among ties
            key = [
                (-np.hypot(*(self.q[j] - self.q[i])) / (1 + 0.1 * len(self.same[i]) * len(self.same[j])))
                for i, j in pairs
            ]
        else:  # wide angular separation, similar ranges (ratio well determined), rare classes
            key = []
            for i, j in pairs:
                sep = abs(float(geo.wrap_angle(self.q_bear[i] - self.q_bear[j])))
                sep = min(sep, np.radians(60.0))
                key.append(-sep / np.sqrt(len(self.same[i]) * len(self.same[j])))
        order = np.argsort(key, kind="stable")
        return [pairs[k] for k in order]

    # ------------------------------------------------------------------ refinement
    def refine_batch(self, t: np.ndarray, theta: np.ndarray, s: np.ndarray, iters: int = 15):
        """Robust Gauss-Newton with re-association for C hypotheses at once.

        Objective: bearing + weak log-range residuals (positions for metric maps) of the matched
        inliers, plus the priors for depth maps; soft-L1 weights (IRLS), analytic Jacobians, a
        little Levenberg damping (compiled: ``solver_kernels.refine_gauss_newton``); matches
        re-associated ``refine_rounds`` times. Returns refined (t (C,2), theta (C,), s (C,)).
        """
        cfg = self.cfg
        C = len(t)
        p = np.column_stack([t, theta, np.log(np.maximum(s, 1e-9))]).astype(float)
        use_prior = self.prior is not None and cfg.prior_weight > 0 and not self.metric
        use_heading = use_prior and self.prior_heading is not None and cfg.prior_heading_sigma_deg > 0
        use_scale = not self.metric and self.scale_prior is not None and cfg.scale_prior_weight > 0
        mu, sd = self.scale_prior if use_scale else (0.0, 1.0)
        for _ in range(cfg.refine_rounds):
            _, inl, match = self.data_cost(p[:, :2], p[:, 2], np.exp(p[:, 3]))
            R = np.ascontiguousarray(self.r[match])  # (C, M, 2) matched candidates
            cam, head = np.zeros((C, 2)), np.zeros(C)
            if use_prior:  # the prior camera each hypothesis is tied to, fixed for this round
                if use_heading:
                    k = min(cfg.prior_knn, self.prior.n)
                    d, j = self.prior.query(p[:, :2], k=k)
                    d, j = d.reshape(C, k), j.reshape(C, k)
                    dth = geo.wrap_angle(self.prior_heading[j] - p[:, 2:3])
                    sel = np.argmin(
                        (d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, 1
                    )
                    jj = j[np.arange(C), sel]
                    head = self.prior_heading[jj].astype(float)
                else:
                    jj = self.prior.query(p[:, :2], k=1)[1]
                cam = np.ascontiguousarray(self.prior.data[jj], dtype=float)
            solver_kernels.refine_gauss_newton(
                p,
                R,
                inl,
                self.metric,
                self.q[:, 0].copy(),
                self.q[:, 1].copy(),
                self.q_bear,
                self.q_range,
                float(self.eps_q),
                float(self.sb),
                float(cfg.refine_log_range_sigma),
                float(cfg.position_sigma_m),
                cam,
                float(cfg.prior_weight) if use_prior else 0.0,
                float(cfg.prior_sigma_m),
                head,
                float(np.radians(cfg.prior_heading_sigma_deg)) if use_heading else 0.0,
                float(mu),
                float(sd),
                float(cfg.scale_prior_weight) if use_scale else 0.0,
                iters,
            )
        return p[:, :2].copy(), geo.wrap_angle(p[:, 2]), np.exp(p[:, 3]) if not self.metric else np.ones(C)


class _PriorGate:
    """Which points lie within ``radius`` of a prior camera: a 1 m grid of sure-inside / sure-outside
    cells, an exact tree query only for cells on the boundary. Same answer as the tree query alone;
    built once per set of prior cameras (a scene) and cached, as every query of a scene shares it."""

    CELL = 1.0

    def __init__(self, cams: np.ndarray, radius: float):
        self.tree = cKDTree(cams)
        self.radius = float(radius)
        pad = radius + 2 * self.CELL
        self.lo = cams.min(0) - pad
        shape = np.ceil((cams.max(0) + pad - self.lo) / self.CELL).astype(int) + 1
        if shape.prod() > 4_000_000:  # cameras spread over kilometres: the tree alone
            shape = np.array([1, 1])
        gx, gy = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
        centres = self.lo + (np.stack([gx, gy], -1).reshape(-1, 2) + 0.5) * self.CELL
        half_diag = self.CELL * math.sqrt(0.5)
        d = self.tree.query(centres, k=1, distance_upper_bound=radius + half_diag + 1e-9)[0].reshape(shape)
        self.state = np.where(d <= radius - half_diag, 1, np.where(d <= radius + half_diag, 2, 0)).astype(np.int8)

    def near(self, t: np.ndarray) -> np.ndarray:
        """(C,) True where a prior camera is within ``radius``."""
        ij = np.floor((t - self.lo) / self.CELL).astype(np.int64)
        inside = (ij >= 0).all(1) & (ij[:, 0] < self.state.shape[0]) & (ij[:, 1] < self.state.shape[1])
        st = np.zeros(len(t), np.int8)
        st[inside] = self.state[ij[inside, 0], ij[inside, 1]]
        out = st == 1
        edge = np.flatnonzero(st == 2)
        if len(edge):
            out[edge] = self.tree.query(t[edge], k=1, distance_upper_bound=self.radius + 1e-9)[0] <= self.radius
        return out


_GATES: dict = {}


def _prior_gate(cams: np.ndarray, radius: float) -> _PriorGate:
    cams = np.ascontiguousarray(cams, dtype=float)
    key = (cams.shape, hash(cams.tobytes()), float(radius))
    if key not in _GATES:
        if len(_GATES) >= 64:
            _GATES.clear()
        _GATES[key] = _PriorGate(cams, radius)
    return _GATES[key]


def solve(
    query_xy,
    query_cls,
    ref_xy,
    ref_cls,
    metric: bool = False,
    config: SolverConfig | dict | None = None,
    prior_xy: np.ndarray | None = None,
    scale_prior: tuple[float, float] | None = None,
    prior_seen: np.ndarray | None = None,
) -> Solution | None:
    """Camera pose in the reference frame, or None when no hypothesis can be formed.

    ``query_xy``: (M, 2) local map; ``query_cls``: (M,) classes; ``ref_xy``/``ref_cls``: the
    candidate reference objects (metric frame); ``metric``: True for GT (metre) local maps,
    False for unscaled depth maps; ``prior_xy``: (P, 2) plausible camera positions (training
    cameras; a third column, their headings in radians, enables the joint pose prior when
    ``prior_heading_sigma_deg`` > 0) or None: hypotheses farther than ``prior_radius_m`` are dropped and the distance
    to the nearest one is a soft cost; ``scale_prior``: (mean, std) of log(metres per local
    unit) for depth maps (see :func:`fit_priors`); ``prior_seen``: (P, N) booleans, prior camera p
    saw reference row n (the matched objects of training queries), for the co-visibility cost
    (``covis_weight``). Inlier indices refer to rows of ``ref_xy``.
    """
    cfg = config if isinstance(config, SolverConfig) else SolverConfig.from_dict(config)
    prior_arr = np.asarray(prior_xy, float).reshape(len(prior_xy), -1) if prior_xy is not None else None
    gate = _prior_gate(prior_arr[:, :2], cfg.prior_radius_m) if prior_arr is not None and len(prior_arr) else None
    prior = gate.tree if gate is not None else None
    pb = _Problem(query_xy, query_cls, ref_xy, ref_cls, metric, cfg, prior, scale_prior)
    if prior is not None and prior_arr.shape[1] >= 3:
        pb.prior_heading = prior_arr[:, 2]
    if prior is not None and prior_seen is not None:
        pb.seen = np.ascontiguousarray(np.asarray(prior_seen, bool).reshape(len(prior_arr), len(pb.r)))
    if pb.m < 2 or len(pb.r) < 2:
        return None
    cand_cost, cand_t, cand_th, cand_s = [], [], [], []
    n_hyp = 0
    best_so_far = np.inf

    def batches():
        if not metric:  # range-free resections first: bearings are what depth maps get right
            for n, (i, j, k) in enumerate(pb.query_triples()):
                if n >= cfg.max_triples:
                    break
                yield pb.triple_hypotheses(i, j, k, cfg.max_triple_hyp)
        for n, (i, j) in enumerate(pb.query_pairs()):
            if n >= cfg.max_pairs:
                break
            yield pb.pair_hypotheses(i, j)

    pending: list[tuple] = []  # prior-gated batches waiting to be scored together

    def flush():
        """Score the pending batches in one pass (fewer, larger array operations) and keep each
        batch's top_k, as if scored one by one."""
        nonlocal best_so_far
        if not pending:
            return
        t = np.concatenate([b[0] for b in pending])
        th = np.concatenate([b[1] for b in pending])
        s = np.concatenate([b[2] for b in pending])
        cost = np.concatenate(
            [
                pb.score(t[o : o + cfg.chunk], th[o : o + cfg.chunk], s[o : o + cfg.chunk])[0]
                for o in range(0, len(t), cfg.chunk)
            ]
        )
        start = 0
        for bt, _, _ in pending:
            for o in range(0, len(bt), cfg.chunk):  # top_k per batch chunk, as before
                lo, hi = start + o, start + min(o + cfg.chunk, len(bt))
                top = lo + np.argsort(cost[lo:hi], kind="stable")[: cfg.top_k]
                cand_cost.append(cost[top])
                cand_t.append(t[top])
                cand_th.append(th[top])
                cand_s.append(s[top])
                best_so_far = min(best_so_far, float(cost[top[0]]) if len(top) else np.inf)
            start += len(bt)
        pending.clear()

    n_pending = 0
    for n_batch, h in enumerate(batches()):
        if n_hyp >= cfg.max_hyp:
            break
        if h is None:
            continue
        t, th, s = h
        if prior is not None and len(t):
            near = gate.near(t)
            t, th, s = t[near], th[near], s[near]
        if len(t):
            pending.append((t, th, s))
            n_pending += len(t)
        n_hyp += len(t)
        # GT maps: score every batch at once for the early stop (every object explained within a sigma)
        if metric or n_pending >= cfg.chunk:
            flush()
            n_pending = 0
        if cfg.early_stop and metric and best_so_far < pb.m and n_batch >= 1:
            break
    flush()
    if not cand_cost:
        return None
    cost = np.concatenate(cand_cost)
    t_all, th_all, s_all = np.concatenate(cand_t), np.concatenate(cand_th), np.concatenate(cand_s)
    order = np.argsort(cost, kind="stable")
    chosen: list[int] = []
    tx, ty, tth = t_all[:, 0].tolist(), t_all[:, 1].tolist(), th_all.tolist()  # scalar maths: many short loops
    two_deg, two_pi = math.radians(2.0), 2.0 * math.pi
    for w in order.tolist():  # the top_k distinct hypotheses (not within 1 m / 2 deg of a better one)
        if len(chosen) >= cfg.top_k:
            break
        if any(
            math.hypot(tx[w] - tx[v], ty[w] - ty[v]) < 1.0
            and abs((tth[w] - tth[v] + math.pi) % two_pi - math.pi) < two_deg
            for v in chosen
        ):
            continue
        chosen.append(w)
    ch = np.array(chosen, int)
    t_r, th_r, s_r = pb.refine_batch(t_all[ch], th_all[ch], s_all[ch])
    c_r, inl_r, match_r = pb.score(t_r, th_r, s_r)
    results = []
    for k in range(len(ch)):
        if not np.all(np.isfinite(t_r[k])) or (
            prior is not None and prior.query(t_r[k], k=1)[0] > 2 * cfg.prior_radius_m
        ):
            continue
        results.append((float(c_r[k]), t_r[k], float(th_r[k]), float(s_r[k]), inl_r[k], match_r[k]))
    if not results:
        return None
    results.sort(key=lambda z: z[0])
    c, t, th, s, inl, match = results[0]
    inliers = [(int(k), int(match[k])) for k in range(pb.m) if inl[k]]
    # confidence: share of explained objects, lowered when a distinct pose is nearly as good
    conf = len(inliers) / pb.m
    for c2, t2, *_ in results[1:]:
        if np.hypot(*(t2 - t)) > 2.0:
            conf *= float(1 - np.exp(-(c2 - c) / 2.0))
            break
    return Solution(float(t[0]), float(t[1]), float(th), float(s), inliers, float(conf), c, n_hyp)


@functools.cache
def warm_up() -> None:
    """Compile (or load from numba's cache) every solver kernel on a tiny problem, so that timed
    queries never include compilation (seconds the first time in a process without a cache).
    Once per process (cached): every scene's evaluation calls it."""
    rng = np.random.default_rng(0)
    ref, ref_cls = rng.uniform(-50, 50, (30, 2)), rng.integers(0, 3, 30)
    q, q_cls = rng.uniform(1, 20, (5, 2)), ref_cls[:5]
    prior, seen = rng.uniform(-50, 50, (20, 3)), rng.random((20, 30)) < 0.3
    for metric in (True, False):
        solve(
            q,
            q_cls,
            ref,
            ref_cls,
            metric=metric,
            config={"covis_weight": 1.0, "prior_heading_sigma_deg": 20.0},
            prior_xy=prior,
            scale_prior=(2.0, 0.5),
            prior_seen=seen,
        )


def fit_priors(train_local_maps_m: list[np.ndarray]) -> tuple[float, float]:
    """Log-scale prior of depth maps from training GT (metre) local maps.

    Depth maps are normalised to a median object range of 1, so their scale in metres per unit
    is the median object range of the view: its log mean and std over training views.
    """
    med = np.array([np.median(np.linalg.norm(np.asarray(m, float), axis=1)) for m in train_local_maps_m])
    med = np.log(med[med > 0])
    return float(med.mean()), float(max(med.std(), 1e-3))
