"""The depth maps' radial bearing distortion, per scene: fitted on the training split, undone
before matching.

Why: in a few scenes the depth local maps' bearings are compressed away from the image centre, as
an uncorrected lens would (several degrees at 25-40 degrees off axis, docs/results.md), while the
noise model treats every bearing error as random. A scene's photos come from its own crowd of
cameras, so one coefficient per scene (the data has no camera model) is what the training split
can fit: the true bearing ``b`` of a depth-map bearing ``d`` is ``d + k d**3`` (:func:`undistort`),
``k`` fitted by least squares on the training queries' detections against their GT local maps
(:func:`fit_scene`). A scene keeps its ``k`` only where the fit is sure of it and it lowers the
off-axis bearing error by a clear margin (:data:`MIN_Z`, :data:`MIN_GAIN`); elsewhere ``k`` is 0
and nothing changes.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from flatlandia.data import localmaps

#: bearing errors beyond this are mismatches, not distortion (left out of the fit)
MAX_ERROR_DEG = 10.0
#: a coefficient is kept only this many standard errors from 0 ...
MIN_Z = 5.0
#: ... and when it lowers the median bearing error beyond :data:`OFF_AXIS_DEG` by this share
MIN_GAIN = 0.2
OFF_AXIS_DEG = 25.0
#: at least this many detections beyond :data:`OFF_AXIS_DEG` to fit on
MIN_OFF_AXIS = 20
#: |k| at most (a bearing of 1 rad moved by 1 rad)
MAX_K = 1.0


def undistort(xy, k: float) -> np.ndarray:
    """(M, 2) a depth local map with its bearings ``d`` moved to ``d + k d**3`` (ranges kept)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if not k:
        return xy
    r = np.hypot(xy[:, 0], xy[:, 1])
    d = np.arctan2(xy[:, 1], xy[:, 0])
    b = d + float(k) * d**3
    return np.column_stack([r * np.cos(b), r * np.sin(b)])


def bearing_pairs(queries: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(depth-map bearings, GT bearings) of every detection of the training queries (radians)."""
    depth, gt = [], []
    for r in queries[queries["split"] == "train"].itertuples(index=False):
        d, g = localmaps.local_map(r, "depth"), localmaps.local_map(r, "gt")
        if len(d) != len(g):
            continue
        depth.append(np.arctan2(d[:, 1], d[:, 0]))
        gt.append(np.arctan2(g[:, 1], g[:, 0]))
    if not depth:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(depth), np.concatenate(gt)


def fit_k(depth: np.ndarray, gt: np.ndarray) -> float:
    """The coefficient ``k`` of :func:`undistort` that best maps ``depth`` bearings onto ``gt``
    (least squares, mismatches beyond :data:`MAX_ERROR_DEG` left out), or 0 when it is not sure and
    useful (:data:`MIN_Z`, :data:`MIN_GAIN`)."""
    err = (np.asarray(gt, float) - np.asarray(depth, float) + math.pi) % (2 * math.pi) - math.pi
    ok = np.isfinite(err) & (np.abs(err) < math.radians(MAX_ERROR_DEG))
    d, e = np.asarray(depth, float)[ok], err[ok]
    off = np.abs(d) > math.radians(OFF_AXIS_DEG)
    if off.sum() < MIN_OFF_AXIS:
        return 0.0
    d3 = d**3
    k = float(np.sum(e * d3) / np.sum(d3 * d3))
    res = e - k * d3
    se = math.sqrt(float(np.mean(res**2)) / float(np.sum(d3 * d3)))
    before = float(np.median(np.abs(e[off])))
    after = float(np.median(np.abs(res[off])))
    if abs(k) < MIN_Z * se or after > (1.0 - MIN_GAIN) * before or abs(k) > MAX_K:
        return 0.0
    return k


def scene_of(ref: pd.DataFrame) -> str | None:
    """The scene id of a reference map (None: a map without one)."""
    return str(ref["scene"].iloc[0]) if "scene" in ref and len(ref) else None


def coefficient(bearing: dict[str, float] | None, ref: pd.DataFrame) -> float:
    """The coefficient of ``ref``'s scene in ``bearing`` (0: none)."""
    return float((bearing or {}).get(scene_of(ref), 0.0))


def fit(scenes: list[tuple[pd.DataFrame, pd.DataFrame]]) -> dict[str, float]:
    """Per scene id, its coefficient (:func:`fit_k` on its training split); scenes without one are
    left out."""
    out = {}
    for ref, q in scenes:
        scene = scene_of(ref)
        k = fit_k(*bearing_pairs(q)) if scene is not None else 0.0
        if k:
            out[scene] = k
    return out
