"""The protocol of "beyond one frame": sequences, simulated odometry and GPS fixes, and what the
priors may hold, built from each scene's recovered query poses.

Why simulated: the published data hold single images with their poses, no capture order and no
phone GPS. A sequence is built from the poses by a fixed rule and its relative poses and fixes are
the truth plus documented noise, drawn from generators seeded by the config's master seed and the
anchor, so a run is reproducible and every row of the table sees the same draws.

- **Sequence rule** (:func:`sequence_rows`): an anchor is a query of the evaluated split (test);
  its companions are the other queries of its scene whose cameras lie within ``radius_m`` of the
  anchor's, nearest first (ties by token), as many as the largest frame count asks. A k-frame
  sequence is the anchor and its k-1 nearest companions; an anchor with fewer companions is
  evaluated with the frames it has.
- **Odometry** (:func:`odometry`): the frames form a chain, anchor first, each companion after the
  one nearer the anchor; each step's true relative pose (forward, left, turn) is perturbed by
  Gaussian noise of sigma ``distance_pct`` % of the step's length on forward and left and
  ``heading_deg`` degrees on the turn, and the noisy steps are composed from the anchor: what
  visual or wheel odometry reports. The solver is told each frame's accumulated sigma (first order:
  the steps' position noise plus each earlier turn's noise swinging the later path).
- **GPS** (:func:`gps_fix`): the anchor's true position plus sigma times a draw of a 2-D standard
  normal (east, north), one draw per anchor shared by every sigma, so rows at 10, 25 and 50 m differ
  by the sigma alone; no compass.
- **Leakage** (:func:`leave_out`): a frame's ground truth reaches its localization only through
  the simulated odometry: the companions' own training cameras (and what they saw) are left out of
  the camera prior, the co-visibility sets and the verifier's features while they are used; the
  anchor, a test query, is never in them. The depth maps' scale prior and the verifier are learned
  once per benchmark from the whole training split (rule solver_priors), as for single frames.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from flatlandia import geo, solver
from flatlandia.sequences import MIN_SIGMA_DEG, MIN_SIGMA_M  # noqa: F401  (the floors, this module's API too)
from flatlandia.solver.priors import Fix
from flatlandia.solver.sequence import relative_pose

#: purposes of the seeded generators (one stream each per anchor)
ODOMETRY, GPS = 1, 2


def rng_for(seed: int, purpose: int, scene: str, token: str) -> np.random.Generator:
    """The generator of one anchor's draws: (master seed, purpose, scene, token), stable across runs
    and platforms (CRC-32 of the names)."""
    return np.random.default_rng(
        [int(seed), int(purpose), zlib.crc32(str(scene).encode()), zlib.crc32(str(token).encode())]
    )


def poses(queries: pd.DataFrame) -> np.ndarray:
    """(N, 3) camera poses x, y (m), theta (rad) of query rows."""
    return np.column_stack(
        [
            queries["x_m"].to_numpy(float),
            queries["y_m"].to_numpy(float),
            np.radians(queries["theta_deg"].to_numpy(float)),
        ]
    ).reshape(-1, 3)


def sequence_rows(queries: pd.DataFrame, split: str, companions: int, radius_m: float) -> list[list[int]]:
    """Per anchor (a query of ``split`` of one scene, in table order), its row positions in
    ``queries``: the anchor, then up to ``companions`` other queries whose cameras lie within
    ``radius_m``, nearest first (ties by token)."""
    xy = queries[["x_m", "y_m"]].to_numpy(float)
    tokens = queries["token"].astype(str).to_numpy()
    tree = cKDTree(xy) if len(xy) else None
    out = []
    for i in np.flatnonzero(queries["split"].to_numpy() == split):
        near = tree.query_ball_point(xy[i], float(radius_m)) if tree is not None else []
        near = [j for j in near if j != i]
        near.sort(key=lambda j: (float(np.hypot(*(xy[j] - xy[i]))), tokens[j]))
        out.append([int(i)] + [int(j) for j in near[:companions]])
    return out


@dataclass
class Odometry:
    """Each frame's simulated pose in the anchor's camera frame and the noise the solver is told."""

    rel: np.ndarray  # (F, 3) dx forward, dy left (m), dtheta (rad); row 0 zeros
    sigma: np.ndarray  # (F, 2) position (m), heading (rad); row 0 zeros


def odometry(frame_poses: np.ndarray, rng: np.random.Generator, distance_pct: float, heading_deg: float) -> Odometry:
    """The chain's noisy relative poses (module docstring, "Odometry") of true poses ``frame_poses``
    (F, 3), anchor first, in chain order."""
    p = np.asarray(frame_poses, float).reshape(-1, 3)
    n = len(p)
    rel = np.zeros((n, 3))
    sigma = np.zeros((n, 2))
    sh = math.radians(heading_deg)
    pos_var = 0.0
    for f in range(1, n):
        step = relative_pose(p[f - 1], p[f])
        length = float(np.hypot(step[0], step[1]))
        noisy = step + np.r_[rng.normal(0.0, distance_pct / 100 * length, 2), rng.normal(0.0, sh)]
        c, s = math.cos(rel[f - 1, 2]), math.sin(rel[f - 1, 2])
        rel[f] = [
            rel[f - 1, 0] + c * noisy[0] - s * noisy[1],
            rel[f - 1, 1] + s * noisy[0] + c * noisy[1],
            float(geo.wrap_angle(rel[f - 1, 2] + noisy[2])),
        ]
        pos_var += (distance_pct / 100 * length) ** 2
        # each earlier frame's heading noise swings the path after it (first order)
        swing = sum(sh**2 * float(np.hypot(*(p[f, :2] - p[g, :2]))) ** 2 for g in range(1, f))
        sigma[f] = [max(math.sqrt(pos_var + swing), MIN_SIGMA_M), max(sh * math.sqrt(f), math.radians(MIN_SIGMA_DEG))]
    return Odometry(rel, sigma)


def gps_fix(truth_xy, draw: np.ndarray, sigma_m: float) -> Fix:
    """The simulated fix of a camera at ``truth_xy``: the truth plus ``sigma_m`` times ``draw``
    (2,), a standard normal draw (east, north)."""
    return Fix(float(truth_xy[0] + sigma_m * draw[0]), float(truth_xy[1] + sigma_m * draw[1]), float(sigma_m))


def gps_draw(seed: int, scene: str, token: str) -> np.ndarray:
    """The anchor's standard normal draw (2,) of :func:`gps_fix`, shared by every sigma."""
    return rng_for(seed, GPS, scene, token).normal(0.0, 1.0, 2)


def leave_out(priors: solver.TrainingPriors | None, queries: pd.DataFrame, tokens) -> solver.TrainingPriors | None:
    """The scene's priors (:func:`flatlandia.solver.scene_priors` of ``queries``) without the
    training cameras of ``tokens`` (a sequence's companions): their poses and what they saw."""
    if priors is None or priors.cameras is None:
        return priors
    train = queries[queries["split"] == "train"]
    keep = ~train["token"].astype(str).isin({str(t) for t in tokens}).to_numpy()
    if keep.all():
        return priors
    if not keep.any():  # no training camera left: no camera prior, co-visibility or verifier
        return replace(priors, cameras=None, seen=None)
    return priors.without_cameras(keep)
