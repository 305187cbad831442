"""Recover query ground truth by registering GT local maps onto their reference map.

A published GT local map is ``p_local = (2/tf) R(-theta) (p_lonlat - cam_lonlat)``: a rigid
copy (known scale) of some reference objects in the camera frame. Registering it back gives
the camera pose and the matched objects. We work in *unit space* (lon/lat times 2/tf), where
the relation is exactly rigid, and measure residuals in metres.

Search: the query's two farthest objects form an anchor pair; every reference pair with the
same length (within the ambiguity tolerance) proposes a pose; a pose is kept when every query
object lands within the tolerance of a distinct reference object (of the same class, when the
query's classes are known). All such solutions are refitted by least squares and ranked by
residual, so near-ties (a second solution within 10 cm) are reported, not hidden.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from flatlandia import config
from flatlandia.geo import UNIT_DEG, rigid_fit_2d, rot2, wrap_angle


@dataclass
class Solution:
    """One registration of a local map onto the reference map (unit space)."""

    ref_idx: tuple[int, ...]
    theta: float  # radians, CCW from +lon of the camera's +x axis (unit space)
    cam: np.ndarray  # (2,) camera position in unit space
    rms_m: float  # RMS residual in metres
    max_m: float  # largest residual in metres


@dataclass
class Recovery:
    """The best solution of one query and what competed with it."""

    best: Solution
    others: list[Solution] = field(default_factory=list)


class PairIndex:
    """All ordered pairs of reference objects sorted by length, for fast anchor look-up."""

    def __init__(self, ref_units: np.ndarray):
        self.ref = np.asarray(ref_units, float)
        n = len(self.ref)
        i, j = np.nonzero(~np.eye(n, dtype=bool))
        d = np.linalg.norm(self.ref[i] - self.ref[j], axis=1)
        order = np.argsort(d, kind="stable")
        self.i, self.j, self.d = i[order], j[order], d[order]
        self.tree = cKDTree(self.ref)

    def pairs_near(self, length: float, tol: float) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = np.searchsorted(self.d, [length - tol, length + tol + 1e-300])
        return self.i[lo:hi], self.j[lo:hi]


def residual_metres(diff_units: np.ndarray, metres_per_degree: tuple[float, float]) -> np.ndarray:
    """Length in metres of unit-space difference vectors (anisotropic: lon degrees are shorter)."""
    mx, my = metres_per_degree
    return np.hypot(diff_units[..., 0] * UNIT_DEG * mx, diff_units[..., 1] * UNIT_DEG * my)


def register(
    local: np.ndarray,
    index: PairIndex,
    metres_per_degree: tuple[float, float],
    tol_m: float = config.section_defaults("recover")["tol_m"],
    local_classes: np.ndarray | None = None,
    ref_classes: np.ndarray | None = None,
    max_alternatives: int = 64,
) -> Recovery | None:
    """Register one GT local map (unit space) onto the reference map; None if nothing fits.

    ``tol_m`` bounds every object's residual in metres: solutions beyond it are not solutions.
    """
    local = np.asarray(local, float)
    m = len(local)
    if m < 2:
        raise ValueError("a local map needs at least 2 objects to be registered")
    tol_u = tol_m / (UNIT_DEG * min(metres_per_degree))  # loosest bound in unit space
    dl = np.linalg.norm(local[:, None] - local[None], axis=-1)
    a, b = np.unravel_index(np.argmax(dl), dl.shape)
    ci, cj = index.pairs_near(dl[a, b], 2 * tol_u)
    if local_classes is not None and ref_classes is not None:
        keep = (ref_classes[ci] == local_classes[a]) & (ref_classes[cj] == local_classes[b])
        ci, cj = ci[keep], cj[keep]
    ang_local = np.arctan2(*(local[b] - local[a])[::-1])
    # Every candidate anchor proposes a pose; keep those where all objects land near the map.
    vec = index.ref[cj] - index.ref[ci]
    theta = np.arctan2(vec[:, 1], vec[:, 0]) - ang_local
    rot = rot2(theta)  # (C, 2, 2)
    t = index.ref[ci] - np.einsum("cij,j->ci", rot, local[a])
    world = np.einsum("cij,mj->cmi", rot, local) + t[:, None, :]
    dist, _ = index.tree.query(world.reshape(-1, 2), k=1, distance_upper_bound=tol_u)
    ok = np.isfinite(dist.reshape(len(ci), m)).all(axis=1)
    found: dict[tuple[int, ...], Solution] = {}
    for w in world[ok]:
        near = index.tree.query_ball_point(w, r=tol_u)
        if local_classes is not None and ref_classes is not None:
            near = [[r for r in cand if ref_classes[r] == local_classes[k]] for k, cand in enumerate(near)]
        if any(len(c) == 0 for c in near):
            continue
        for assign in itertools.islice(itertools.product(*near), max_alternatives):
            if len(set(assign)) < m or assign in found:
                continue
            sol = _refit(local, index.ref, assign, metres_per_degree)
            if sol.max_m <= tol_m:
                found[assign] = sol
    if not found:
        return None
    ranked = sorted(found.values(), key=lambda s: (s.rms_m, s.ref_idx))
    return Recovery(best=ranked[0], others=ranked[1:])


def _refit(
    local: np.ndarray, ref: np.ndarray, assign: tuple[int, ...], metres_per_degree: tuple[float, float]
) -> Solution:
    dst = ref[list(assign)]
    theta, t = rigid_fit_2d(local, dst)
    res = residual_metres(local @ rot2(theta).T + t - dst, metres_per_degree)
    return Solution(
        ref_idx=tuple(int(x) for x in assign),
        theta=float(wrap_angle(theta)),
        cam=t,
        rms_m=float(np.sqrt(np.mean(res**2))),
        max_m=float(res.max()),
    )


def classify_ambiguity(rec: Recovery, ref_classes: np.ndarray, exact_m: float = 1e-3) -> str:
    """How a query's registration stands.

    - ``unique``: no second solution within the tolerance.
    - ``exact_fit``: the best fit is exact (published GT maps are exact copies) and every
      competitor is not; the residual decides.
    - ``same_classes``: competitors fit equally well but assign the same class to every
      query object, so the class labels are certain even if the objects are not.
    - ``unresolved``: equally good solutions that disagree on classes.
    """
    if not rec.others:
        return "unique"
    best, second = rec.best, rec.others[0]
    if best.rms_m < exact_m <= second.rms_m:
        return "exact_fit"
    ties = [o for o in rec.others if o.rms_m < exact_m] or [second]
    bc = ref_classes[list(best.ref_idx)]
    if all(np.array_equal(bc, ref_classes[list(o.ref_idx)]) for o in ties):
        return "same_classes"
    return "unresolved"
