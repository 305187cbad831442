"""A pose scored against chance: the log-likelihood ratio of what the camera saw there.

Why: the MSAC cost counts matched objects and their residuals, so a place dense in common classes
(a row of trees explains any three trees) fits as well as the true one, objects the pose says the
camera must have seen but did not cost nothing, and the cost says nothing about how likely a fit
is by chance. Here a pose's score is the log-likelihood ratio of the detections under the map
against the detections being chance (Lang et al. 2010, astrometry.net's verification; Atanasov
et al. 2016, semantic localization with missed detections):

- each detection explained by a same-class map object gains log N(bearing) + log N(log range)
  (the solver's one noise model, fitted on the training split per range bin:
  :mod:`flatlandia.solver.noise`) minus the log density, in (bearing, log
  range), of an object of its class lying there at random: the map's local density of that class
  times the range squared (area = range^2 d bearing d log range); a detection nothing explains is
  clutter and counts 0; each map object explains at most one detection;
- every map object in the field of view and range (fitted from the training detections) that no
  detection explains costs log(1 - p_d), with the detection probability p_d(class, range, bearing,
  the share of the mapping views near the pose that saw it) fitted on the training split (the
  published matches say which objects each training query saw, its pose which were in view); an
  explained object gains log(p_d / p_d0), p_d0 the rate of the chance hypothesis (the same fit
  without the views);
- the pose was fitted to its detections (its 3 parameters and the scale), so a fit's bearings and
  ranges agree better than chance would have them: a correction of the same size for every pose of
  a query (about one nat per fitted parameter), so it changes no ranking and is left to the
  calibration of the answer's probability (:mod:`flatlandia.solver.calibration`) rather than taken
  off each pose (taking the best-fitting detections' terms off each pose, as astrometry.net's quad
  stars do not vote, was tried on the validation split: it favours poses that explain fewer
  detections, 55.7 % right against 57.1 % without it).

The model (:class:`LikelihoodModel`) is fitted once per benchmark with the learned priors (rule
solver_priors, :func:`fit`) and validated when read. The compiled loop is in ``likelihood_kernels``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import classes, geo
from flatlandia.data import localmaps
from flatlandia.solver import likelihood_kernels as lk
from flatlandia.solver import verify
from flatlandia.solver.likelihood_kernels import LikelihoodTerms
from flatlandia.solver.noise import RANGE_EDGES_M, NoiseModel, bins

#: |bearing| bins (degrees) of p_d
BEARING_EDGES_DEG = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 180.0)
#: the field of view and range: these quantiles of the training detections' |bearing| and range
FOV_QUANTILE = 0.99
#: pseudo-weight of "no view" in the share of nearby views that saw an object (a lone far view
#: says little)
VIEW_FLOOR = 0.5


@dataclass(frozen=True)
class LikelihoodModel:
    """The field of view and the detection probability, fitted on a training split (the noise of
    what is detected is the solver's one noise model, :mod:`flatlandia.solver.noise`)."""

    fov_half_deg: float
    max_range_m: float
    intercept: float  # p_d given the views near the pose
    cls_logit: tuple[float, ...]  # per class id
    range_logit: tuple[float, ...]  # per range bin
    bear_logit: tuple[float, ...]  # per |bearing| bin
    share_w: float
    nocam_w: float
    intercept0: float  # p_d0: without the views (the chance hypothesis' rate)
    cls_logit0: tuple[float, ...]
    range_logit0: tuple[float, ...]
    bear_logit0: tuple[float, ...]
    in_view: int = 0  # training (pose, object in view) pairs p_d was fitted on

    def __post_init__(self):
        nb, na, nk = len(RANGE_EDGES_M) - 1, len(BEARING_EDGES_DEG) - 1, classes.N_CLASSES
        sizes = {
            "range_logit": nb,
            "range_logit0": nb,
            "bear_logit": na,
            "bear_logit0": na,
            "cls_logit": nk,
            "cls_logit0": nk,
        }
        for f in fields(self):
            v = getattr(self, f.name)
            values = v if isinstance(v, tuple) else (v,)
            if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in values):
                raise ValueError(f"{f.name}: every value must be a finite number, got {v!r}")
            if f.name in sizes and len(values) != sizes[f.name]:
                raise ValueError(f"{f.name}: expected {sizes[f.name]} values, got {len(values)}")
        if not (0 < self.fov_half_deg <= 180 and self.max_range_m > 0):
            raise ValueError(f"field of view {self.fov_half_deg} deg and range {self.max_range_m} m out of range")

    def to_dict(self) -> dict:
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict, source: str | Path = "likelihood model") -> LikelihoodModel:
        """The model as :meth:`to_dict` writes it, checked field by field (each a number or a list
        of its size, finite within its bound: a text is no list of digits, 1e308 no logit); one
        InputError naming ``source`` and the field."""
        from flatlandia.plumbing import validate
        from flatlandia.plumbing.errors import InputError

        nb, na, nk = len(RANGE_EDGES_M) - 1, len(BEARING_EDGES_DEG) - 1, classes.N_CLASSES
        w = validate.MAX_LOGIT_WEIGHT
        specs = {  # field: (values: None for one number, largest magnitude: None for a count)
            "fov_half_deg": (None, 180.0),
            "max_range_m": (None, validate.MAX_LOCAL_COORD),
            "intercept": (None, w),
            "cls_logit": (nk, w),
            "range_logit": (nb, w),
            "bear_logit": (na, w),
            "share_w": (None, w),
            "nocam_w": (None, w),
            "intercept0": (None, w),
            "cls_logit0": (nk, w),
            "range_logit0": (nb, w),
            "bear_logit0": (na, w),
            "in_view": (None, None),
        }
        d = validate.json_object(d, source, "likelihood", tuple(specs))
        values = {}
        for name, (size, bound) in specs.items():
            where = f"likelihood {name}"
            if name not in d:
                if name == "in_view":
                    continue  # a count of the fit, kept for the record (0 when absent)
                raise InputError(source, f"{where} is missing")
            if bound is None:
                values[name] = validate.whole(d[name], source, where)
            elif size is None:
                values[name] = validate.finite(d[name], source, where, -bound, bound)
            else:
                values[name] = validate.numbers(d[name], source, where, size, -bound, bound)
        try:
            return cls(**values)
        except ValueError as e:  # the signs and ranges __post_init__ checks
            raise InputError(source, f"likelihood: {e}") from None

    def terms(self, metric: bool, position_sigma_m: float, noise: NoiseModel) -> LikelihoodTerms:
        """The model as the kernel reads it, for a GT (``metric``, residuals in metres of sigma
        ``position_sigma_m``: the published GT maps are exact copies, nothing to fit) or depth map
        (the residuals' sigmas of ``noise``, the solver's one noise model)."""
        a = np.asarray
        return LikelihoodTerms(
            bool(metric),
            *noise.terms(),
            float(position_sigma_m),
            math.radians(self.fov_half_deg),
            float(self.max_range_m),
            np.radians(a(BEARING_EDGES_DEG, float)),
            float(self.intercept),
            a(self.cls_logit, float),
            a(self.range_logit, float),
            a(self.bear_logit, float),
            float(self.share_w),
            float(self.nocam_w),
            float(self.intercept0),
            a(self.cls_logit0, float),
            a(self.range_logit0, float),
            a(self.bear_logit0, float),
            float(VIEW_FLOOR),
        )


# ----------------------------------------------------------------------------- the views near a pose


def view_weights(tree, heading, t, theta) -> tuple[np.ndarray, np.ndarray]:
    """(C, k) kernel weights and indices of the mapping views near poses ``t`` (C, 2), ``theta``:
    the verifier's kernel (:data:`flatlandia.solver.verify.KERNEL_M`, ``KERNEL_DEG``, within
    ``KERNEL_RADIUS_M``, the ``KERNEL_KNN`` nearest); weight 0 where there is none. ``tree``: a
    cKDTree of the views' positions (None: no views), ``heading`` their headings (None: ignored)."""
    t = np.asarray(t, float).reshape(-1, 2)
    n = len(t)
    if tree is None or tree.n == 0:
        return np.zeros((n, 1)), np.zeros((n, 1), np.int64)
    k = min(verify.KERNEL_KNN, tree.n)
    d, j = tree.query(t, k=k, distance_upper_bound=verify.KERNEL_RADIUS_M)
    d, j = d.reshape(n, k), np.minimum(j, tree.n - 1).reshape(n, k).astype(np.int64)
    dth = geo.wrap_angle(heading[j] - np.asarray(theta, float).reshape(-1, 1)) if heading is not None else 0.0
    with np.errstate(invalid="ignore"):
        w = np.exp(-0.5 * (d / verify.KERNEL_M) ** 2 - 0.5 * (dth / math.radians(verify.KERNEL_DEG)) ** 2)
    return np.where(np.isfinite(d), w, 0.0), j


def view_share(w: np.ndarray, j: np.ndarray, seen: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """((C, N) share of the kernel that saw each object, (C,) share that no view fills), as the
    kernel computes them (``seen`` (P, N); None: no views)."""
    den = w.sum(1) + VIEW_FLOOR
    if seen is None:
        return np.zeros((len(w), 0)), np.ones(len(w))
    share = np.einsum("ck,ckn->cn", w, seen[j].astype(float)) / den[:, None]
    return share, VIEW_FLOOR / den


def seen_lists(priors) -> tuple[np.ndarray, np.ndarray]:
    """(ptr, idx): view p saw candidate rows ``idx[ptr[p]:ptr[p + 1]]`` (``priors.seen`` as lists,
    made once per query's priors); a single empty view without them."""
    cached = priors._seen_lists
    if cached is None:
        if priors.seen is None:
            cached = (np.zeros(2, np.int64), np.zeros(0, np.int64))
        else:
            cam, obj = np.nonzero(priors.seen)
            ptr = np.r_[0, np.cumsum(np.bincount(cam, minlength=priors.seen.shape[0]))].astype(np.int64)
            cached = (ptr, obj.astype(np.int64))
        priors._seen_lists = cached
    return cached


# ----------------------------------------------------------------------------- fitting


def field_of_view(queries: list[pd.DataFrame]) -> tuple[float, float]:
    """(half field of view in degrees, range in metres): the :data:`FOV_QUANTILE` of the training
    detections' |bearing| and range (their GT local maps)."""
    xy = [localmaps.local_map(r, "gt") for q in queries for r in q[q["split"] == "train"].itertuples(index=False)]
    xy = np.vstack(xy) if xy else np.zeros((0, 2))
    if not len(xy):
        raise ValueError("no training detections to fit the field of view on")
    bear = np.degrees(np.abs(np.arctan2(xy[:, 1], xy[:, 0])))
    return float(np.quantile(bear, FOV_QUANTILE)), float(np.quantile(np.hypot(*xy.T), FOV_QUANTILE))


def visibility_rows(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]], fov_half_deg: float, max_range_m: float
) -> pd.DataFrame:
    """Per training query and map object in its field of view and range at its true pose: the
    class, range, |bearing|, the share of the kernel of the *other* training views near the pose
    that saw it and the share no view fills (:func:`view_share`), and whether the query detected
    it (the published matches)."""
    from scipy.spatial import cKDTree

    from flatlandia.solver.priors import seen_mask

    out = []
    for ref, q in scenes:
        train = q[q["split"] == "train"].reset_index(drop=True)
        if not len(train) or not len(ref):
            continue
        xy, cls, obj = (
            ref[["x_m", "y_m"]].to_numpy(float),
            ref["class_id"].to_numpy(np.int64),
            ref["obj_idx"].to_numpy(),
        )
        cams = np.column_stack([train["x_m"], train["y_m"]]).astype(float)
        head = np.radians(train["theta_deg"].to_numpy(float))
        seen = seen_mask(obj, [np.asarray(v, int) for v in train["ref_idx"]])
        for i, r in enumerate(train.itertuples(index=False)):
            others = np.arange(len(train)) != i
            tree = cKDTree(cams[others]) if others.any() else None
            w, j = view_weights(tree, head[others], cams[i][None], head[i])
            share, nocam = view_share(w, j, seen[others] if others.any() else None)
            loc = geo.world_to_local(xy, cams[i], head[i])
            rng, bear = np.hypot(*loc.T), np.degrees(np.abs(np.arctan2(loc[:, 1], loc[:, 0])))
            det = np.isin(obj, np.asarray(r.ref_idx, int))
            inview = (loc[:, 0] > 0) & (bear <= fov_half_deg) & (rng <= max_range_m)
            sel = np.flatnonzero(inview)
            out.append(
                pd.DataFrame(
                    {
                        "cls": cls[sel],
                        "range_m": rng[sel],
                        "bearing_deg": bear[sel],
                        "share": share[0, sel] if share.shape[1] else 0.0,
                        "nocam": float(nocam[0]),
                        "detected": det[sel],
                    }
                )
            )
    return pd.concat(out, ignore_index=True)


def _logistic(rows: pd.DataFrame, views: bool) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """(intercept, class logits, range logits, bearing logits, share weight, no-view weight) of a
    logistic regression of ``detected`` on one-hot class, range bin and |bearing| bin (and, with
    ``views``, the share and the no-view share); L2-regularised (scikit-learn's lbfgs, deterministic)."""
    from scipy import sparse
    from sklearn.linear_model import LogisticRegression

    nk, nb, na = classes.N_CLASSES, len(RANGE_EDGES_M) - 1, len(BEARING_EDGES_DEG) - 1
    n = len(rows)
    cols = [
        rows["cls"].to_numpy(np.int64),
        nk + bins(RANGE_EDGES_M, rows["range_m"].to_numpy(float)),
        nk + nb + bins(BEARING_EDGES_DEG, rows["bearing_deg"].to_numpy(float)),
    ]
    x = sparse.csr_matrix((np.ones(3 * n), (np.tile(np.arange(n), 3), np.concatenate(cols))), shape=(n, nk + nb + na))
    if views:
        x = sparse.hstack([x, sparse.csr_matrix(rows[["share", "nocam"]].to_numpy(float))]).tocsr()
    y = rows["detected"].to_numpy(bool)
    fit = LogisticRegression(C=1.0, max_iter=2000).fit(x, y)
    w = fit.coef_.ravel()
    extra = (float(w[-2]), float(w[-1])) if views else (0.0, 0.0)
    return float(fit.intercept_[0]), w[:nk], w[nk : nk + nb], w[nk + nb : nk + nb + na], *extra


def fit(scenes: list[tuple[pd.DataFrame, pd.DataFrame]]) -> LikelihoodModel:
    """The model from the training split of ``scenes`` (reference map, queries): the field of view
    and range (:func:`field_of_view`) and p_d with and without the views (:func:`visibility_rows`)."""
    fov, max_range = field_of_view([q for _, q in scenes])
    rows = visibility_rows(scenes, fov, max_range)
    i1, c1, r1, a1, ws, wn = _logistic(rows, True)
    i0, c0, r0, a0, _, _ = _logistic(rows, False)
    t = tuple
    return LikelihoodModel(
        fov, max_range, i1, t(c1.tolist()), t(r1.tolist()), t(a1.tolist()), ws, wn,
        i0, t(c0.tolist()), t(r0.tolist()), t(a0.tolist()), int(len(rows)),
    )  # fmt: skip


# ----------------------------------------------------------------------------- scoring


def pose_llr(problem, priors, model: LikelihoodModel, density_radius_m: float, t, theta, s):
    """(C,) log-likelihood ratio against chance of poses ``t`` (C, 2), ``theta``, scale ``s`` of one
    query (:class:`~flatlandia.solver.problem.Problem`, its :class:`~flatlandia.solver.priors.Priors`:
    the views near a pose and what they saw), (C, M) the map row explaining each detection (-1:
    none) and (C, 7) its parts (:data:`flatlandia.solver.likelihood_kernels.PARTS`)."""
    t = np.ascontiguousarray(t, dtype=float).reshape(-1, 2)
    theta = np.ascontiguousarray(theta, dtype=float).ravel()
    s = np.ascontiguousarray(s, dtype=float).ravel() if not problem.metric else np.ones(len(t))
    w, j = view_weights(priors.tree, priors.heading, t, theta)
    seen_ptr, seen_idx = seen_lists(priors)
    if priors.seen is None:
        w = np.zeros_like(w)
    if priors.scale is not None:  # the chance hypothesis does not know the pose's scale: its mean square
        mu, sd = priors.scale
        chance_log_s2 = np.full(len(t), 2.0 * mu + 2.0 * sd * sd)
    else:
        chance_log_s2 = 2.0 * np.log(s)
    return lk.pose_llr(
        t[:, 0].copy(),
        t[:, 1].copy(),
        theta,
        s,
        chance_log_s2,
        problem.terms,
        problem.candidates,
        problem.rx,
        problem.ry,
        problem.rc.astype(np.int64),
        problem.log_density(density_radius_m),
        np.ascontiguousarray(w),
        np.ascontiguousarray(j, dtype=np.int64),
        seen_ptr,
        seen_idx,
        model.terms(problem.metric, problem.cfg.position_sigma_m, problem.noise),
    )
