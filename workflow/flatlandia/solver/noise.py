"""The depth maps' noise model: one value that the MSAC cost, the refinement and the likelihood ratio
all read.

Why one model: the MSAC cost used to carry its own hand-set bearing sigma and a tangent bearing
error while the likelihood ratio used a noise fitted on the training split and a wrapped angle, so
the two disagreed on what an inlier is and a change to the noise touched eight places. Here:

- **per range bin** (:data:`RANGE_EDGES_M`) the bearing sigma and the log-range sigma of the
  training detections of the depth maps against their GT local maps (after each query's scale), a
  Gaussian beside a uniform of outliers (:func:`fit`);
- **per scene** the camera's radial bearing coefficient (:mod:`flatlandia.solver.distortion`),
  undone before matching and before the sigmas are fitted;
- **one bearing error**: the wrapped angle between the query's bearing and the candidate's
  (:func:`bearing_error`), in the MSAC cost, the refinement, the sequences and the likelihood alike.

The MSAC cost scores with the model's sigmas, its ranges weighed ``solver.msac_range_inflation``
times more loosely (a truncated cost that chooses among thousands of hypotheses is kept from
rejecting a true match whose range is off) and the refinement ``solver.refine_range_inflation``
times more loosely again; without a fitted model (no learned priors: a map of your own) it uses
:meth:`NoiseModel.constant` of ``solver.default_bearing_sigma_deg`` and
``solver.default_log_range_sigma``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from numba import njit

from flatlandia import geo
from flatlandia.data import localmaps
from flatlandia.solver import distortion

#: range bins (metres) of the noise model (and of the likelihood's detection probability)
RANGE_EDGES_M = (0.0, 5.0, 10.0, 20.0, 35.0, 60.0, 100.0, math.inf)
N_BINS = len(RANGE_EDGES_M) - 1
#: outliers of the noise fit: a uniform over this many degrees of bearing / this span of log range
OUTLIER_SPAN_DEG, OUTLIER_SPAN_LOG = 60.0, 6.0
#: the smallest sigma a fit may return (a bin of exact copies is not noise-free)
FLOOR_BEARING_DEG, FLOOR_LOG_RANGE = 0.05, 0.02
#: a bin with fewer detections takes its neighbour's sigmas
MIN_PER_BIN = 10


class NoiseTerms(NamedTuple):
    """The model as the compiled kernels read it: per range bin, sigmas in radians and log units."""

    range_edges: np.ndarray  # (B + 1,) metres (last: inf)
    bearing_sigma: np.ndarray  # (B,) rad
    log_range_sigma: np.ndarray  # (B,)


@njit(cache=True, inline="always")
def range_bin(edges, r):
    """Index of the range bin of ``edges`` holding ``r`` (clamped to the first and last bins)."""
    nb = edges.shape[0] - 1
    for b in range(nb):
        if r < edges[b + 1]:
            return b
    return nb - 1


@njit(cache=True, inline="always")
def bearing_error(along, across):
    """The wrapped angle (rad) between a direction and an offset ``along`` / ``across`` it: the one
    bearing error of the solver (the MSAC cost, the refinement and the likelihood)."""
    return math.atan2(across, along)


@dataclass(frozen=True)
class NoiseModel:
    """Per range bin of :data:`RANGE_EDGES_M` the depth maps' bearing and log-range sigmas, and per
    scene id its radial bearing coefficient (:mod:`flatlandia.solver.distortion`)."""

    bearing_sigma_deg: tuple[float, ...]
    log_range_sigma: tuple[float, ...]
    distortion: dict[str, float] = field(default_factory=dict)
    detections: int = 0  # training detections the sigmas were fitted on (0: not fitted)

    def __post_init__(self):
        for name in ("bearing_sigma_deg", "log_range_sigma"):
            v = getattr(self, name)
            if len(v) != N_BINS or not all(isinstance(x, (int, float)) and math.isfinite(x) and x > 0 for x in v):
                raise ValueError(f"{name}: expected {N_BINS} positive finite values, got {v!r}")

    @classmethod
    def constant(cls, bearing_sigma_deg: float, log_range_sigma: float) -> NoiseModel:
        """One sigma for every range bin and no distortion: the model of a map without a fitted one."""
        return cls((float(bearing_sigma_deg),) * N_BINS, (float(log_range_sigma),) * N_BINS)

    def bearing_k(self, scene) -> float:
        """The radial bearing coefficient of ``scene``'s depth maps (0: none)."""
        return float(self.distortion.get(str(scene), 0.0))

    def terms(self, range_inflation: float = 1.0) -> NoiseTerms:
        """The kernels' view, the log-range sigmas times ``range_inflation``."""
        return NoiseTerms(
            np.asarray(RANGE_EDGES_M, float),
            np.radians(np.asarray(self.bearing_sigma_deg, float)),
            np.asarray(self.log_range_sigma, float) * float(range_inflation),
        )

    def to_dict(self) -> dict:
        return {
            "range_edges_m": [e if math.isfinite(e) else None for e in RANGE_EDGES_M],
            "bearing_sigma_deg": list(self.bearing_sigma_deg),
            "log_range_sigma": list(self.log_range_sigma),
            "distortion": dict(self.distortion),
            "detections": int(self.detections),
        }

    @classmethod
    def from_dict(cls, d, source: str | Path = "noise model") -> NoiseModel:
        """The model as :meth:`to_dict` writes it, checked field by field (the range edges must be
        this solver's: a model fitted on other bins is refitted, not reinterpreted); one InputError
        naming ``source`` and the field."""
        from flatlandia.plumbing import names, validate
        from flatlandia.plumbing.errors import InputError

        keys = ("range_edges_m", "bearing_sigma_deg", "log_range_sigma", "distortion", "detections")
        d = validate.json_object(d, source, "noise", keys)
        missing = [k for k in keys if k not in d]
        if missing:
            raise InputError(source, f"noise lacks {', '.join(missing)}")
        edges = [e if math.isfinite(e) else None for e in RANGE_EDGES_M]
        if d["range_edges_m"] != edges:
            raise InputError(
                source,
                f"noise range_edges_m {validate.shown(d['range_edges_m'])} are not this solver's {edges}: "
                "rule solver_priors refits the model",
            )
        sb = validate.numbers(d["bearing_sigma_deg"], source, "noise bearing_sigma_deg", N_BINS, 0.0, 180.0)
        sr = validate.numbers(d["log_range_sigma"], source, "noise log_range_sigma", N_BINS, 0.0, 10.0)
        if min(sb) <= 0 or min(sr) <= 0:
            raise InputError(source, "noise: every sigma must be > 0")
        dist = d["distortion"]
        if not isinstance(dist, dict):
            raise InputError(
                source, f"noise distortion must be an object of scene id -> coefficient, got {validate.shown(dist)}"
            )
        if len(dist) > validate.MAX_SCENES:
            raise InputError(source, f"noise distortion names {len(dist)} scenes, at most {validate.MAX_SCENES}")
        ks = {
            names.plain_name(scene, source, "noise distortion scene id"): validate.finite(
                k, source, f"noise distortion of scene {validate.shown(scene)}", -distortion.MAX_K, distortion.MAX_K
            )
            for scene, k in dist.items()
        }
        return cls(tuple(sb), tuple(sr), ks, validate.whole(d["detections"], source, "noise detections"))


# ----------------------------------------------------------------------------- fitting


def bins(edges, v) -> np.ndarray:
    """Index of the bin of ``edges`` holding each of ``v`` (clamped), as :func:`range_bin`."""
    return np.clip(np.searchsorted(np.asarray(edges, float), v, side="right") - 1, 0, len(edges) - 2)


def mixture_sigma(e: np.ndarray, span: float, floor: float, iters: int = 50) -> float:
    """Sigma of the Gaussian part of residuals ``e`` drawn from a Gaussian and a uniform over
    ``span`` (EM from the robust MAD estimate); ``floor`` without enough residuals."""
    e = np.asarray(e, float)
    if len(e) < MIN_PER_BIN:
        return floor
    sigma = max(1.4826 * float(np.median(np.abs(e))), floor)
    share = 0.9
    for _ in range(iters):
        g = share * np.exp(-0.5 * (e / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma)
        u = (1 - share) / span
        r = g / (g + u)
        share = float(np.clip(r.mean(), 1e-3, 1 - 1e-3))
        sigma = max(math.sqrt(float((r * e * e).sum() / max(r.sum(), 1e-9))), floor)
    return sigma


def detection_residuals(queries: list[pd.DataFrame], bearing_k=None) -> pd.DataFrame:
    """Per training detection: its true range (m), bearing error (rad, :func:`bearing_error`'s
    wrapped angle) and log-range error of the depth map (after the query's scale: its log ranges'
    mean, with the m/(m-1) correction), each scene's depth maps corrected by its ``bearing_k`` (one
    per table; None: none)."""
    rows = []
    for q, k in zip(queries, bearing_k if bearing_k is not None else [0.0] * len(queries)):
        for r in q[q["split"] == "train"].itertuples(index=False):
            gt, d = localmaps.local_map(r, "gt"), distortion.undistort(localmaps.local_map(r, "depth"), k)
            m = len(gt)
            if m < 2:
                continue
            rg, rd = np.hypot(*gt.T), np.hypot(*d.T)
            ok = (rg > 0) & (rd > 0)
            eb = geo.wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(gt[:, 1], gt[:, 0]))
            lr = np.log(np.where(ok, rd, 1.0)) - np.log(np.where(ok, rg, 1.0))
            lr = (lr - lr[ok].mean()) * math.sqrt(m / (m - 1))
            rows.append(pd.DataFrame({"range_m": rg[ok], "bearing_err": eb[ok], "log_range_err": lr[ok]}))
    return (
        pd.concat(rows, ignore_index=True)
        if rows
        else pd.DataFrame(columns=["range_m", "bearing_err", "log_range_err"])
    )


def bin_sigmas(res: pd.DataFrame) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(bearing sigma in degrees, log-range sigma) per range bin of :data:`RANGE_EDGES_M`
    (:func:`mixture_sigma`); a bin with fewer than :data:`MIN_PER_BIN` detections takes its
    neighbour's."""
    b = bins(RANGE_EDGES_M, res["range_m"].to_numpy(float))
    eb, er = res["bearing_err"].to_numpy(float), res["log_range_err"].to_numpy(float)
    sb, sr = [], []
    for k in range(N_BINS):
        sel = b == k
        sb.append(math.degrees(mixture_sigma(eb[sel], math.radians(OUTLIER_SPAN_DEG), math.radians(FLOOR_BEARING_DEG))))
        sr.append(mixture_sigma(er[sel], OUTLIER_SPAN_LOG, FLOOR_LOG_RANGE))
        if sel.sum() < MIN_PER_BIN and k > 0:
            sb[-1], sr[-1] = sb[-2], sr[-2]
    for k in range(N_BINS - 2, -1, -1):  # leading empty bins take the next one's
        if (b == k).sum() < MIN_PER_BIN:
            sb[k], sr[k] = sb[k + 1], sr[k + 1]
    return tuple(sb), tuple(sr)


def fit(scenes: list[tuple[pd.DataFrame, pd.DataFrame]], bearing_correction: bool) -> NoiseModel:
    """The model from the training split of ``scenes`` (reference map, queries): with
    ``bearing_correction`` each scene's radial coefficient first (:func:`distortion.fit`), then the
    sigmas per range bin of the corrected depth maps (:func:`bin_sigmas`)."""
    ks = distortion.fit(scenes) if bearing_correction else {}
    res = detection_residuals([q for _, q in scenes], [distortion.coefficient(ks, ref) for ref, _ in scenes])
    sb, sr = bin_sigmas(res)
    return NoiseModel(sb, sr, ks, int(len(res)))
