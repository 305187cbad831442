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

A city is not a scene map: the index ranks every place of the city, and the pool the solver refines
holds only what the best few regions offered, so the more places compete the likelier a middling
pool is a chance fit. :class:`MapSize` lowers such an answer's log-odds in proportion to the log of
how many more objects the index ranked than a scene map has (one term for single frames, one for
sequences), fitted on the cities' validation answers (rule city_calibration, :func:`fit_map_size`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: an answer within this of the truth is right (the headline's (5 m, 5 deg))
RIGHT_M, RIGHT_DEG = 5.0, 5.0
#: the features of the calibration, in order
FEATURES = ("log_odds", "log_objects", "log_frames", "agreement")
#: log-odds of a share are clipped to this (a pool of one pose is sure of itself, not infinitely)
MAX_LOG_ODDS = 20.0
#: the answer kinds calibrated apart: one frame, and a sequence of several
KINDS = ("frame", "sequence")


def log_evidence(t, theta, key, ok=None) -> tuple[np.ndarray, float]:
    """(log_place (C,), log_pool): per pose the log of the evidence ``exp(-key)`` summed over the
    poses within (:data:`RIGHT_M`, :data:`RIGHT_DEG`) of it, and over the whole pool (poses where
    ``ok`` and ``key`` is finite; -inf where not ``ok``)."""
    t = np.asarray(t, float).reshape(-1, 2)
    theta = np.asarray(theta, float).ravel()
    key = np.asarray(key, float).ravel()
    ok = np.isfinite(key) if ok is None else np.asarray(ok, bool) & np.isfinite(key)
    out = np.full(len(key), -np.inf)
    if not ok.any():
        return out, -np.inf
    k0 = key[ok].min()
    w = np.where(ok, np.exp(-(key - k0)), 0.0)
    dist = np.hypot(t[:, None, 0] - t[None, :, 0], t[:, None, 1] - t[None, :, 1])
    turn = np.abs((theta[:, None] - theta[None, :] + np.pi) % (2 * np.pi) - np.pi)
    near = (dist < RIGHT_M) & (turn < math.radians(RIGHT_DEG))
    with np.errstate(divide="ignore"):
        out[ok] = np.log((near[ok] * w[None]).sum(1)) - k0
    return out, float(np.log(w.sum()) - k0)


def null_share(log_place, log_pool, null_key: float | None = None) -> np.ndarray:
    """Each place's share of the evidence: ``exp(log_place)`` over the pool's, together with the
    null hypothesis' ``exp(-null_key)`` (None: no null hypothesis) when one is fitted."""
    log_place = np.asarray(log_place, float)
    total = np.asarray(log_pool, float) if null_key is None else np.logaddexp(log_pool, -float(null_key))
    with np.errstate(invalid="ignore"):
        out = np.exp(log_place - total)
    return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)


def pose_masses(t, theta, key, ok=None, null_key: float | None = None) -> np.ndarray:
    """(C,) each pose's share of the pool's evidence: the softmax of ``-key`` (C,) over the poses
    where ``ok``, summed over the poses within (:data:`RIGHT_M`, :data:`RIGHT_DEG`) of it; 0 where
    not ``ok``. With a ``null_key`` the null hypothesis ("the query fits none of these places":
    every detection chance, or a place no hypothesis reached) holds ``exp(-null_key)`` of the
    evidence beside the poses (:func:`null_share`)."""
    log_place, log_pool = log_evidence(t, theta, key, ok)
    return null_share(log_place, log_pool, null_key)


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


#: bounds of a map-size term (:class:`MapSize`): the log-odds taken off an even answer per e-fold
#: of the map (1 would divide its odds by the map's growth), and how much of that each unit of
#: log-odds spares
MAX_SHIFT, MAX_PER_LOG_ODDS = 2.0, 1.0


def logit(p) -> np.ndarray:
    """log(p / (1 - p)), p clipped into (0, 1) so that a sure answer stays finite."""
    p = np.clip(np.asarray(p, float), 1e-12, 1.0 - 1e-12)
    return np.log(p) - np.log1p(-p)


@dataclass(frozen=True)
class MapTerm:
    """One kind's map-size term: an answer of log-odds z loses ``max(0, shift - per_log_odds * z)``
    per e-fold of the map beyond a scene map's size."""

    shift: float
    per_log_odds: float

    def __post_init__(self):
        if not (math.isfinite(self.shift) and 0 <= self.shift <= MAX_SHIFT):
            raise ValueError(f"a map-size shift must lie in [0, {MAX_SHIFT:g}], got {self.shift}")
        if not (math.isfinite(self.per_log_odds) and 0 <= self.per_log_odds <= MAX_PER_LOG_ODDS):
            raise ValueError(f"a map-size per_log_odds must lie in [0, {MAX_PER_LOG_ODDS:g}], got {self.per_log_odds}")

    def loss(self, z: np.ndarray, efolds: np.ndarray) -> np.ndarray:
        return efolds * np.maximum(0.0, self.shift - self.per_log_odds * z)


@dataclass(frozen=True)
class MapSize:
    """The map-size correction of a city's answers: logit P' = logit P - e * max(0, shift -
    per_log_odds * logit P), e = max(0, log(map objects / ``reference_objects``)) the e-folds by
    which the index's map outgrows a scene map (the median of the maps :class:`Calibration` was
    fitted on), one :class:`MapTerm` for single frames (``frame``) and one for sequences. The more
    places compete, the likelier a middling answer is a chance fit, while a pool sure of itself
    stays sure (validation split, docs/results.md); a scene map, or a smaller search (a fix's
    region), is left as it is, and no answer is ever raised or reordered within a map."""

    reference_objects: float
    frame: MapTerm
    sequence: MapTerm
    answers: int  # validation answers of the cities it was fitted on

    def __post_init__(self):
        if not (math.isfinite(self.reference_objects) and self.reference_objects >= 1):
            raise ValueError(f"a map-size correction needs reference_objects >= 1, got {self.reference_objects}")

    def efolds(self, objects: float) -> float:
        """By how many e-folds a map of ``objects`` objects outgrows a scene map (0 if it does not)."""
        return max(0.0, math.log(max(float(objects), 1.0) / self.reference_objects))

    def adjust(self, probability, objects: float, frames: int = 1) -> np.ndarray:
        """(N,) the probabilities of answers searched among ``objects`` map objects."""
        p = np.asarray(probability, float).ravel()
        e = self.efolds(objects)
        if e == 0.0:
            return p
        z = logit(p)
        loss = (self.frame if frames <= 1 else self.sequence).loss(z, e)
        out = 1.0 / (1.0 + np.exp(-(z - loss)))
        return np.where(np.isfinite(p) & (loss > 0), np.minimum(out, p), p)

    def to_dict(self) -> dict:
        return {
            "reference_objects": self.reference_objects,
            "frame": {"shift": self.frame.shift, "per_log_odds": self.frame.per_log_odds},
            "sequence": {"shift": self.sequence.shift, "per_log_odds": self.sequence.per_log_odds},
            "answers": self.answers,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str | Path = "map-size correction", where: str = "map_size") -> MapSize:
        """The correction as :meth:`to_dict` writes it, checked field by field
        (:func:`flatlandia.plumbing.validate.map_size`); one InputError naming ``source`` and the field."""
        from flatlandia.plumbing import validate

        validate.map_size(d, source, MAX_SHIFT, MAX_PER_LOG_ODDS, where)
        terms = [MapTerm(float(d[k]["shift"]), float(d[k]["per_log_odds"])) for k in ("frame", "sequence")]
        return cls(float(d["reference_objects"]), *terms, int(d["answers"]))


@dataclass(frozen=True)
class Calibration:
    """The fitted maps of single frames and of sequences (either None: the pool's share is used as
    it is), and the cities' map-size correction (None: none; :meth:`in_map` applies it)."""

    frame: Logistic | None = None
    sequence: Logistic | None = None
    map_size: MapSize | None = None
    #: the null hypothesis' key in a single frame's pool (:func:`pose_masses`; None: none)
    null_key: float | None = None

    def probability(self, mass, objects, frames: int = 1, agreement=1.0) -> np.ndarray:
        """(N,) P(within (5 m, 5 deg)) of answers with pool shares ``mass`` and ``objects`` seen, of
        ``frames`` frames of which a share ``agreement`` answered alone the same place."""
        fit = self.frame if frames <= 1 else self.sequence
        mass = np.clip(np.asarray(mass, float).ravel(), 0.0, 1.0)
        return mass if fit is None else fit(features(mass, objects, frames, agreement))

    def in_map(self, probability, map_objects: float, frames: int = 1) -> np.ndarray:
        """(N,) ``probability`` of answers whose search ranked ``map_objects`` objects (a city's
        index), lowered by the map-size correction (unchanged without one)."""
        p = np.asarray(probability, float).ravel()
        return p if self.map_size is None else self.map_size.adjust(p, map_objects, frames)

    def to_dict(self) -> dict:
        out = {"features": list(FEATURES)}
        for k in KINDS:
            f = getattr(self, k)
            out[k] = None if f is None else {"intercept": f.intercept, "weights": list(f.weights), "answers": f.answers}
        if self.map_size is not None:
            out["map_size"] = self.map_size.to_dict()
        if self.null_key is not None:
            out["null_key"] = self.null_key
        return out

    @classmethod
    def from_dict(cls, d: dict, source: str | Path = "calibration") -> Calibration:
        """The calibration as :meth:`to_dict` writes it, checked field by field: an object of
        ``features``, ``frame`` and ``sequence`` (each null or an object of an ``intercept`` and
        ``weights`` within :data:`~flatlandia.plumbing.validate.MAX_LOGIT_WEIGHT` and a count of
        ``answers``) and an optional ``map_size``; one InputError naming ``source`` and the field."""
        from flatlandia.plumbing import validate
        from flatlandia.plumbing.errors import InputError

        d = validate.json_object(d, source, "calibration", ("features", *KINDS, "map_size", "null_key"))
        if d.get("features") != list(FEATURES):
            raise InputError(
                source, f"calibration features {validate.shown(d.get('features'))} are not {list(FEATURES)}"
            )
        parts = {}
        for k in KINDS:
            v, where = d.get(k), f"calibration {k}"
            if v is None:
                parts[k] = None
                continue
            v = validate.json_object(v, source, where, ("intercept", "weights", "answers"))
            bound = validate.MAX_LOGIT_WEIGHT
            intercept = validate.finite(v.get("intercept"), source, f"{where} intercept", -bound, bound)
            weights = validate.numbers(v.get("weights"), source, f"{where} weights", None, -bound, bound)
            answers = validate.whole(v.get("answers"), source, f"{where} answers")
            try:
                parts[k] = Logistic(intercept, weights, answers)
            except ValueError as e:  # the number of weights
                raise InputError(source, f"{where}: {e}") from None
        if d.get("map_size") is not None:
            parts["map_size"] = MapSize.from_dict(d["map_size"], source, "calibration map_size")
        if d.get("null_key") is not None:
            bound = validate.MAX_LOGIT_WEIGHT
            parts["null_key"] = validate.finite(d["null_key"], source, "calibration null_key", -bound, bound)
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


def fit_map_size(answers, reference_objects: float) -> MapSize:
    """The map-size correction fitted on cities' validation answers (columns ``probability``: the
    calibrated probability before the correction, ``map_objects``: the objects the index ranked,
    ``frames``, ``right``): per kind (one frame, sequences), the :class:`MapTerm` within its bounds
    that maximizes the answers' Bernoulli likelihood (scipy's L-BFGS-B from no correction:
    deterministic); no correction for a kind with fewer than 20 answers in maps larger than
    ``reference_objects``, or a single outcome."""
    from scipy.optimize import minimize

    frames = np.asarray(answers["frames"], int)
    z = logit(answers["probability"])
    e = np.maximum(0.0, np.log(np.maximum(np.asarray(answers["map_objects"], float), 1.0) / reference_objects))
    y = np.asarray(answers["right"], bool)
    terms = {}
    for kind, sel in (("frame", frames <= 1), ("sequence", frames > 1)):
        sel = sel & (e > 0) & np.isfinite(z)
        if sel.sum() < 20 or y[sel].all() or not y[sel].any():
            terms[kind] = MapTerm(0.0, 0.0)
            continue
        zs, es, sign = z[sel], e[sel], np.where(y[sel], -1.0, 1.0)

        def loss(v, zs=zs, es=es, sign=sign):
            return float(np.sum(np.logaddexp(0.0, sign * (zs - es * np.maximum(0.0, v[0] - v[1] * zs)))))

        v = minimize(loss, [0.0, 0.0], method="L-BFGS-B", bounds=[(0.0, MAX_SHIFT), (0.0, MAX_PER_LOG_ODDS)]).x
        terms[kind] = MapTerm(float(v[0]), float(v[1]))
    return MapSize(float(reference_objects), terms["frame"], terms["sequence"], int(len(y)))


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
