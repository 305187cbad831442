"""What the training split tells the solver about a pose: camera positions (and headings), the
log-scale of depth maps, and which objects the training cameras saw (co-visibility).

Why apart from the scoring: the priors gate hypotheses, add costs and add rows to the
refinement; keeping them in one object keeps those three uses consistent. They travel as one
value, :class:`TrainingPriors` (built for a scene by :func:`scene_priors`), from the rules that
read them to :func:`flatlandia.solver.solve`; :class:`Priors` is that value as one query's
solver reads it (gate, costs, refinement rows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from flatlandia import geo
from flatlandia.data import localmaps
from flatlandia.solver import kernels
from flatlandia.solver.calibration import Calibration
from flatlandia.solver.kernels import CoSeen, PriorTerms
from flatlandia.solver.noise import NoiseModel
from flatlandia.solver.settings import SolverConfig


@dataclass(frozen=True)
class TrainingPriors:
    """Everything the solver may know beyond the query and the map, as one value; any part may be
    None (it then costs and gates nothing).

    ``cameras``: (P, 3) training cameras, x, y in metres and heading in radians (the camera
    prior's gate and cost); ``seen``: (P, N) booleans, camera p saw candidate row n of the map the
    value is for (co-visibility cost and gate); ``scale``: (mean, std) of log(metres per local
    unit) of depth maps; ``verifier``: picks among the best hypotheses of a depth map;
    ``likelihood``: the field of view and detection probability of the likelihood ratio against
    chance (:mod:`flatlandia.solver.likelihood`); ``calibration``: maps a pool's log-odds to the
    probability of an answer (:mod:`flatlandia.solver.calibration`); ``noise``: the depth maps'
    noise model that the MSAC cost and the likelihood read (:mod:`flatlandia.solver.noise`; None:
    the settings' constant one); ``bearing_k``: the scene's radial bearing correction of depth maps
    (of ``noise``, :mod:`flatlandia.solver.distortion`). Metric (GT) local maps use the cameras and
    co-visibility only."""

    cameras: np.ndarray | None = None
    seen: np.ndarray | None = None
    scale: tuple[float, float] | None = None
    #: a :class:`flatlandia.solver.verify.Verifier` (typed loosely: the verifier and the likelihood
    #: model read these priors, so this module cannot import them without a loop)
    verifier: Any = None
    likelihood: Any = None  # a :class:`flatlandia.solver.likelihood.LikelihoodModel`
    calibration: Calibration | None = None
    noise: NoiseModel | None = None
    #: the scene's radial bearing coefficient of depth maps (:mod:`flatlandia.solver.distortion`; 0: none)
    bearing_k: float = 0.0

    def rows(self, idx) -> TrainingPriors:
        """The same priors for the candidate rows ``idx`` of the map (a proposal's objects)."""
        return self if self.seen is None else replace(self, seen=self.seen[:, np.asarray(idx, int)])

    def without_cameras(self, keep) -> TrainingPriors:
        """The priors of the cameras where ``keep`` (bool per camera): leave-one-out fits."""
        if self.cameras is None:
            return self
        seen = self.seen[keep] if self.seen is not None else None
        return replace(self, cameras=self.cameras[keep], seen=seen)


@dataclass(frozen=True)
class Fix:
    """A position fix of the camera (a phone's GPS) and optionally a compass heading, as a Gaussian
    likelihood: the solver keeps only poses within ``GATE_SIGMAS`` sigmas of the fix and adds
    (distance / ``sigma_m``)^2 [+ (heading difference / ``heading_sigma_deg``)^2] to a pose's cost
    (the MSAC cost is a sum of squared normalised residuals, so this is the fix's negative
    log-likelihood on the same scale). ``x``, ``y``: metres of the map's frame; ``heading``: radians,
    counter-clockwise from east (the solver's theta)."""

    x: float
    y: float
    sigma_m: float
    heading: float | None = None
    heading_sigma_deg: float | None = None

    #: poses farther than this many sigmas from the fix are refused (4: 0.03 % of true poses of a
    #: 2-D Gaussian fix lie beyond)
    GATE_SIGMAS = 4.0
    #: a query's objects lie within this of its camera (99th percentile of the training split's
    #: object ranges: 97 m): a caller crops its map to the gate plus this
    VIEW_M = 150.0

    def __post_init__(self):
        if not (np.isfinite(self.x) and np.isfinite(self.y) and np.isfinite(self.sigma_m) and self.sigma_m > 0):
            raise ValueError(f"a fix needs a finite position and a positive sigma, got {self}")
        if (self.heading is None) != (self.heading_sigma_deg is None):
            raise ValueError("a compass heading needs both heading and heading_sigma_deg")
        if self.heading_sigma_deg is not None and not self.heading_sigma_deg > 0:
            raise ValueError(f"heading_sigma_deg must be positive, got {self.heading_sigma_deg}")

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y], float)

    @property
    def gate_m(self) -> float:
        """Poses within this of the fix are kept."""
        return self.GATE_SIGMAS * self.sigma_m

    @property
    def crop_m(self) -> float:
        """Map objects within this of the fix can be seen from a kept pose."""
        return self.gate_m + self.VIEW_M

    def near(self, t) -> np.ndarray:
        """(C,) True for positions within the gate."""
        t = np.asarray(t, float).reshape(-1, 2)
        return np.hypot(t[:, 0] - self.x, t[:, 1] - self.y) <= self.gate_m

    def cost(self, t, theta) -> np.ndarray:
        """(C,) (distance / sigma)^2, plus (heading difference / heading sigma)^2 with a compass."""
        t = np.asarray(t, float).reshape(-1, 2)
        out = ((t[:, 0] - self.x) ** 2 + (t[:, 1] - self.y) ** 2) / self.sigma_m**2
        if self.heading is not None:
            dth = geo.wrap_angle(np.asarray(theta, float).ravel() - self.heading)
            out = out + (dth / math.radians(self.heading_sigma_deg)) ** 2
        return out

    def widened(self, extra_m: float) -> Fix:
        """The fix of a camera ``extra_m`` metres from this one in an unknown direction (a sequence's
        companion frame), as its gate needs it: the gate widened by ``extra_m``, no compass."""
        return Fix(self.x, self.y, self.sigma_m + float(extra_m) / self.GATE_SIGMAS)


def training_priors(queries: pd.DataFrame, settings: SolverConfig | dict | None = None):
    """The solver's priors from one scene's training split: (prior cameras (P, 3) as x, y, heading
    in radians, or None when ``camera_prior`` is off; per prior camera the reference ``obj_idx`` it
    saw, for the co-visibility cost, or None). Test queries never contribute. ``settings``: the
    solver's (a dict is read strictly, unset keys at the schema's defaults)."""
    cfg = SolverConfig.of(settings)
    if not cfg.camera_prior:
        return None, None
    tr = queries[queries["split"] == "train"]
    prior = np.column_stack([tr["x_m"], tr["y_m"], np.radians(tr["theta_deg"])]).astype(float)
    seen = [np.asarray(v, int) for v in tr["ref_idx"]] if float(cfg.covis_weight) > 0 else None
    return prior, seen


def seen_mask(obj_idx, prior_seen) -> np.ndarray | None:
    """(P, N) booleans: prior camera p saw the reference object of row n (``obj_idx``: the rows'
    ids; ``prior_seen``: per prior camera the ``obj_idx`` it saw, from :func:`training_priors`);
    None without co-visibility sets. Ids outside ``obj_idx`` are ignored."""
    if prior_seen is None:
        return None
    pos = {int(o): k for k, o in enumerate(obj_idx)}
    seen = np.zeros((len(prior_seen), len(pos)), bool)
    for k, objs in enumerate(prior_seen):
        seen[k, [pos[int(o)] for o in objs if int(o) in pos]] = True
    return seen


def camera_priors(ref: pd.DataFrame, queries: pd.DataFrame, settings: dict | None = None) -> TrainingPriors:
    """The camera priors of one scene's whole map (rows of ``ref``): its training cameras and what
    they saw (:func:`training_priors`); :func:`flatlandia.solver.scene_priors` adds the learned ones."""
    cams, seen_objs = training_priors(queries, settings)
    seen = seen_mask(ref["obj_idx"].to_numpy(), seen_objs) if cams is not None else None
    return TrainingPriors(cams, seen)


def fit_scale(train_local_maps_m: list[np.ndarray]) -> tuple[float, float]:
    """Log-scale prior of depth maps from training GT (metre) local maps.

    Depth maps are normalised to a median object range of 1, so their scale in metres per unit
    is the median object range of the view: its log mean and std over training views.
    """
    med = np.array([np.median(np.linalg.norm(np.asarray(m, float), axis=1)) for m in train_local_maps_m])
    med = np.log(med[med > 0])
    return float(med.mean()), float(max(med.std(), 1e-3))


def depth_scale_prior(queries, settings: SolverConfig | dict | None = None) -> tuple[float, float] | None:
    """The solver's log-scale prior of depth maps (:func:`fit_scale`) from the training split of
    every scene's queries (a list of query tables), or None when ``solver.scale_prior`` is off."""
    if not SolverConfig.of(settings).scale_prior:
        return None
    train = [localmaps.xy(c) for q in queries for c in q.loc[q["split"] == "train", "gt_local_xy_m"]]
    return fit_scale(train)


class PriorGate:
    """Which points lie within ``radius`` of a prior camera: an exact tree query, and once the tree
    has answered about as many points as a 1 m grid over the cameras has cells (``GRID_AFTER``), a
    grid of sure-inside / sure-outside cells with the tree only for boundary cells. Same answer
    either way; cached per set of prior cameras. Why lazily: the grid's cost grows with the cameras'
    extent, which pays off over the many queries of a scene, not for the camera set the city search
    hands one query (docs/measurements.md, "Code paths")."""

    CELL = 1.0
    GRID_AFTER = 0.125  # build the grid once the points queried exceed this share of its cells
    MAX_CELLS = 4_000_000  # cameras spread wider (kilometres): the tree alone

    def __init__(self, cams: np.ndarray, radius: float):
        self.tree = cKDTree(cams)
        self.radius = float(radius)
        pad = radius + 2 * self.CELL
        self.lo = cams.min(0) - pad
        self.shape = np.ceil((cams.max(0) + pad - self.lo) / self.CELL).astype(int) + 1
        self.cells = int(self.shape.prod())
        self.queried = 0  # points answered by the tree alone so far
        self.state = None  # the grid, once built

    @property
    def tree_only(self) -> bool:
        """No grid (yet, or ever for cameras spread over kilometres)."""
        return self.state is None

    def _build_grid(self) -> None:
        gx, gy = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        centres = self.lo + (np.stack([gx, gy], -1).reshape(-1, 2) + 0.5) * self.CELL
        half_diag = self.CELL * math.sqrt(0.5)
        bound = self.radius + half_diag + 1e-9
        d = self.tree.query(centres, k=1, distance_upper_bound=bound)[0].reshape(tuple(self.shape))
        r = self.radius
        self.state = np.where(d <= r - half_diag, 1, np.where(d <= r + half_diag, 2, 0)).astype(np.int8)

    def _tree_near(self, t: np.ndarray) -> np.ndarray:
        return self.tree.query(t, k=1, distance_upper_bound=self.radius + 1e-9)[0] <= self.radius

    def near(self, t: np.ndarray) -> np.ndarray:
        """(C,) True where a prior camera is within ``radius``."""
        if self.state is None:
            self.queried += len(t)
            if self.cells > self.MAX_CELLS or self.queried < self.GRID_AFTER * self.cells:
                return self._tree_near(t)
            self._build_grid()
        ij = np.floor((t - self.lo) / self.CELL).astype(np.int64)
        inside = (ij >= 0).all(1) & (ij[:, 0] < self.state.shape[0]) & (ij[:, 1] < self.state.shape[1])
        st = np.zeros(len(t), np.int8)
        st[inside] = self.state[ij[inside, 0], ij[inside, 1]]
        out = st == 1
        edge = np.flatnonzero(st == 2)
        if len(edge):
            out[edge] = self._tree_near(t[edge])
        return out


_GATES: dict = {}


def prior_gate(cams: np.ndarray, radius: float) -> PriorGate:
    """The gate of a set of prior cameras, cached (every query of a scene shares its cameras)."""
    cams = np.ascontiguousarray(cams, dtype=float)
    key = (cams.shape, hash(cams.tobytes()), float(radius))
    if key not in _GATES:
        if len(_GATES) >= 256:
            _GATES.clear()
        _GATES[key] = PriorGate(cams, radius)
    return _GATES[key]


def coseen(seen: np.ndarray) -> CoSeen:
    """Which candidates some prior camera saw together (the co-visibility gate of hypotheses)."""
    cam, obj = np.nonzero(seen)
    return CoSeen(*kernels.coseen_pairs(cam, obj, seen.shape[1]))


class Priors:
    """The priors of one query; any of them may be absent (then it costs nothing)."""

    def __init__(self, cfg, metric: bool, given: TrainingPriors | None = None, n_ref: int = 0, fix: Fix | None = None):
        given = given or TrainingPriors()
        self.fix = fix  # a position fix (GPS) of this camera, or None
        prior_xy, prior_seen = given.cameras, given.seen
        self.cfg = cfg
        self.metric = metric
        self.scale = given.scale  # (mean, std) of log(metres per local unit), or None
        self.likelihood = given.likelihood  # the likelihood ratio's model, or None
        self.calibration = given.calibration  # the answers' probability, or None (the pool's share)
        cams = np.asarray(prior_xy, float).reshape(len(prior_xy), -1) if prior_xy is not None else None
        self.gate = prior_gate(cams[:, :2], cfg.prior_radius_m) if cams is not None and len(cams) else None
        self.tree = self.gate.tree if self.gate is not None else None  # prior camera positions, or None
        has_cams = self.tree is not None
        self.heading = cams[:, 2] if has_cams and cams.shape[1] >= 3 else None  # (P,) radians, or None
        self.seen = None  # (P, N) bool: prior camera p saw candidate n, or None
        if has_cams and prior_seen is not None:
            self.seen = np.ascontiguousarray(np.asarray(prior_seen, bool).reshape(len(cams), n_ref))
        #: the candidates some prior camera saw together (the hypothesis gate), or None
        self.coseen = coseen(self.seen) if self.seen is not None and not metric else None
        self._seen_lists = None  # ``seen`` as lists per view (the likelihood ratio's; made when first asked)

    # ------------------------------------------------------------------ gating
    def near(self, t) -> np.ndarray:
        """(C,) True for the positions within ``prior_radius_m`` of a prior camera (all without cameras)
        and within the fix's gate (with a fix)."""
        if not len(t):
            return np.ones(len(t), bool)
        out = self.gate.near(t) if self.gate is not None else np.ones(len(t), bool)
        if self.fix is not None:
            out &= self.fix.near(t)
        return out

    def too_far(self, t) -> bool:
        """A refined pose that drifted beyond twice the gate radius from every prior camera."""
        return bool(self.drifted(np.asarray(t, float).reshape(1, 2))[0])

    def drifted(self, t) -> np.ndarray:
        """(C,) :meth:`too_far` of finite positions ``t`` (C, 2), in one tree query."""
        if self.tree is None or not len(t):
            return np.zeros(len(t), bool)
        return self.tree.query(np.asarray(t, float).reshape(-1, 2), k=1)[0] > 2 * self.cfg.prior_radius_m

    # ------------------------------------------------------------------ costs
    def _heading_on(self) -> bool:
        return self.heading is not None and self.cfg.prior_heading_sigma_deg > 0

    def covis_on(self) -> bool:
        cfg = self.cfg
        return self.seen is not None and cfg.covis_weight > 0 and (not self.metric or cfg.covis_metric)

    def neighbours(self, t):
        """Distances and indices (C, k) of the ``prior_knn`` nearest prior cameras (k = 1 when
        neither the heading prior nor co-visibility needs more), or None without cameras."""
        if self.tree is None:
            return None
        cfg = self.cfg
        t = np.asarray(t, float).reshape(-1, 2)
        k = min(cfg.prior_knn, self.tree.n) if self._heading_on() or self.covis_on() else 1
        # farther cameras change nothing: their prior cost is capped and co-visibility ignores them
        bound = max(cfg.tau * cfg.prior_sigma_m, cfg.covis_radius_m if self.covis_on() else 0.0) + 1e-9
        d, j = self.tree.query(t, k=k, distance_upper_bound=bound)
        return d.reshape(len(t), k), np.minimum(j, self.tree.n - 1).reshape(len(t), k)  # missing: d = inf

    def _pose_sq(self, theta, nb) -> np.ndarray:
        """(C,) squared normalised distance of poses to the prior cameras (position [+ heading])."""
        cfg = self.cfg
        d, j = nb
        if not self._heading_on():
            return (d[:, 0] / cfg.prior_sigma_m) ** 2
        dth = geo.wrap_angle(self.heading[j] - np.asarray(theta).reshape(-1, 1))
        return np.min((d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, axis=1)

    def cost(self, t, s, theta, nb) -> np.ndarray:
        """(C,) prior cost: pose vs the nearest prior camera, log-scale; each capped at tau^2 (the
        fix's cost is :meth:`fix_cost`, apart: the verifier's features read this one)."""
        cfg = self.cfg
        tau2 = cfg.tau**2
        out = np.zeros(len(t))
        if self.tree is not None and cfg.prior_weight > 0:
            out += cfg.prior_weight * np.minimum(self._pose_sq(theta, nb), tau2)
        if not self.metric and self.scale is not None and cfg.scale_prior_weight > 0:
            mu, sd = self.scale
            out += cfg.scale_prior_weight * np.minimum(((np.log(s) - mu) / sd) ** 2, tau2)
        return out

    def fix_cost(self, t, theta) -> np.ndarray:
        """(C,) the fix's cost (:meth:`Fix.cost`; uncapped: a likelihood, and the gate bounds it), 0
        without a fix."""
        return np.zeros(len(np.asarray(t).reshape(-1, 2))) if self.fix is None else self.fix.cost(t, theta)

    def covis_cost(self, t, inl, match, nb) -> np.ndarray:
        """(C,) co-visibility cost: ``covis_weight`` per inlier whose candidate no prior camera within
        ``covis_radius_m`` of the pose saw together with the most of the others (best single camera)."""
        if not self.covis_on():
            return np.zeros(len(t))
        return self.cfg.covis_weight * (inl.sum(1) - self.covis_counts(nb, match, inl))

    def covis_counts(self, nb, match, inl) -> np.ndarray:
        """(C,) inliers that the best single prior camera within ``covis_radius_m`` among ``nb``
        (distances, indices (C, k)) saw together."""
        d, j = nb
        return kernels.covis_counts(
            np.ascontiguousarray(d),
            np.ascontiguousarray(j, dtype=np.int64),
            self.seen,
            match,
            inl,
            float(self.cfg.covis_radius_m),
        )

    # ------------------------------------------------------------------ refinement
    def refine_terms(self, p: np.ndarray) -> PriorTerms:
        """The prior rows of the refinement for poses ``p`` (C, 4), each tied to one prior camera
        for this round (the nearest, or the best in position and heading)."""
        cfg = self.cfg
        n = len(p)
        use_pose = self.tree is not None and cfg.prior_weight > 0 and not self.metric
        use_heading = use_pose and self._heading_on()
        use_scale = not self.metric and self.scale is not None and cfg.scale_prior_weight > 0
        mu, sd = self.scale if use_scale else (0.0, 1.0)
        cam, head = self._tied_cameras(p, use_heading) if use_pose else (np.zeros((n, 2)), np.zeros(n))
        return PriorTerms(
            cam,
            float(cfg.prior_weight) if use_pose else 0.0,
            float(cfg.prior_sigma_m),
            head,
            float(np.radians(cfg.prior_heading_sigma_deg)) if use_heading else 0.0,
            float(mu),
            float(sd),
            float(cfg.scale_prior_weight) if use_scale else 0.0,
        )

    def _tied_cameras(self, p: np.ndarray, use_heading: bool):
        """Position (C, 2) and heading (C,) of the prior camera each pose is tied to: the nearest,
        or with the heading prior the best in position and heading of the ``prior_knn`` nearest."""
        cfg = self.cfg
        n = len(p)
        head = np.zeros(n)
        if use_heading:
            k = min(cfg.prior_knn, self.tree.n)
            d, j = self.tree.query(p[:, :2], k=k)
            d, j = d.reshape(n, k), j.reshape(n, k)
            dth = geo.wrap_angle(self.heading[j] - p[:, 2:3])
            sel = np.argmin((d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, 1)
            jj = j[np.arange(n), sel]
            head = self.heading[jj].astype(float)
        else:
            jj = self.tree.query(p[:, :2], k=1)[1]
        return np.ascontiguousarray(self.tree.data[jj], dtype=float), head
