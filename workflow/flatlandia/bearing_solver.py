"""A geometric 3DoF solver for depth-based local maps: hypothesise from class pairs, score bearings.

Facts it is built on (measured on the published data): in depth local maps the *bearing* of
each object from the camera is accurate (median error 0.2-2.2 deg per scene) while ranges are
noisy and unscaled; query object classes are known; GT local maps are exact rigid copies.

1. Hypotheses: every pair of query objects (i, j) and every ordered pair of candidate reference
   objects (a, b) of the same classes gives a similarity (scale, rotation, translation) taking
   the query points onto them; its translation is the camera position, its rotation the heading.
2. Score: a query object is an inlier when a reference object of its class lies within
   ``bearing_tol_deg`` of its bearing and within a factor ``range_ratio`` of its (hypothesis-
   scaled) range; the hypothesis with most inliers (then the smallest bearing residual) wins.
3. Refine: least squares on the inliers' bearings (and weakly on ranges) over (x, y, theta).
The confidence is the inlier share of the query objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from . import geo


@dataclass
class Pose:
    x: float
    y: float
    theta: float  # radians, CCW from east
    inliers: list[tuple[int, int]]  # (query index, reference index)
    confidence: float


def _similarity_from_pairs(q: np.ndarray, r: np.ndarray, i: int, j: int, a: np.ndarray, b: np.ndarray):
    """Vectorised 2-point similarity q_i->r_a, q_j->r_b for many (a, b): scale, theta, t (C,2)."""
    dq = q[j] - q[i]
    dr = r[b] - r[a]
    s = np.linalg.norm(dr, axis=1) / max(np.linalg.norm(dq), 1e-12)
    theta = np.arctan2(dr[:, 1], dr[:, 0]) - np.arctan2(dq[1], dq[0])
    c, sn = np.cos(theta), np.sin(theta)
    qi = q[i]
    rq = np.stack([c * qi[0] - sn * qi[1], sn * qi[0] + c * qi[1]], axis=1)
    t = r[a] - s[:, None] * rq
    return s, theta, t


def _score(q_bear: np.ndarray, q_range: np.ndarray, q_cls: np.ndarray, ref: np.ndarray, ref_cls: np.ndarray,
           s: np.ndarray, theta: np.ndarray, t: np.ndarray, tol: float, ratio: float):
    """Inlier counts and mean bearing residual of C hypotheses (vectorised)."""
    rel = ref[None, :, :] - t[:, None, :]  # (C, N, 2) reference in a world frame at the camera
    rb = np.arctan2(rel[..., 1], rel[..., 0]) - theta[:, None]  # bearings in the camera frame
    rr = np.linalg.norm(rel, axis=-1)  # (C, N)
    db = np.abs(geo.wrap_angle(rb[:, None, :] - q_bear[None, :, None]))  # (C, M, N)
    pred = s[:, None] * q_range[None, :]  # (C, M) hypothesis-scaled ranges
    ok_range = (rr[:, None, :] < pred[..., None] * ratio) & (rr[:, None, :] > pred[..., None] / ratio)
    same = q_cls[:, None] == ref_cls[None, :]  # (M, N)
    cost = np.where(same[None] & ok_range & (db < tol), db, np.inf)
    best = cost.min(axis=2)  # (C, M)
    inl = np.isfinite(best)
    n = inl.sum(axis=1)
    mean_res = np.where(n > 0, np.where(inl, best, 0).sum(axis=1) / np.maximum(n, 1), np.inf)
    return n, mean_res, cost.argmin(axis=2), inl


def solve(query_xy: np.ndarray, query_cls: np.ndarray, ref_xy: np.ndarray, ref_cls: np.ndarray,
          bearing_tol_deg: float = 3.0, coarse_tol_deg: float = 15.0, range_ratio: float = 3.0,
          max_hyp: int = 200_000, top_k: int = 20, chunk: int = 4096,
          prior_xy: np.ndarray | None = None, prior_radius_m: float = 15.0) -> Pose | None:
    """Pose of the camera given a (depth or GT) local map and candidate reference objects.

    Hypotheses are scored with a loose bearing tolerance (their position is only as good as the
    noisy range ratio of two objects), the ``top_k`` best are refined on their inliers' bearings,
    re-scored with the tight tolerance at the refined pose, and the best refined pose wins.
    ``prior_xy`` (e.g. the training cameras of the scene) keeps only hypotheses within
    ``prior_radius_m`` of one of them: cameras stand where people walk.
    """
    q = np.asarray(query_xy, float)
    r = np.asarray(ref_xy, float)
    qc, rc = np.asarray(query_cls), np.asarray(ref_cls)
    m = len(q)
    if m < 2 or len(r) < 2:
        return None
    q_bear = np.arctan2(q[:, 1], q[:, 0])
    q_range = np.linalg.norm(q, axis=1)
    prior = cKDTree(np.asarray(prior_xy, float)) if prior_xy is not None and len(prior_xy) else None
    loose, tight = np.radians(coarse_tol_deg), np.radians(bearing_tol_deg)
    pairs = [(i, j) for i in range(m) for j in range(m) if i < j and np.linalg.norm(q[j] - q[i]) > 1e-9]
    # widest angular separation first: best-conditioned hypotheses
    pairs.sort(key=lambda p: -abs(geo.wrap_angle(q_bear[p[0]] - q_bear[p[1]])))
    cand_n, cand_res, cand_s, cand_th, cand_t = [], [], [], [], []
    n_hyp = 0
    for i, j in pairs:
        a = np.flatnonzero(rc == qc[i])
        b = np.flatnonzero(rc == qc[j])
        if len(a) == 0 or len(b) == 0:
            continue
        aa, bb = np.meshgrid(a, b, indexing="ij")
        aa, bb = aa.ravel(), bb.ravel()
        keep = aa != bb
        aa, bb = aa[keep], bb[keep]
        for k in range(0, len(aa), chunk):
            s, th, t = _similarity_from_pairs(q, r, i, j, aa[k:k + chunk], bb[k:k + chunk])
            n, res, _, _ = _score(q_bear, q_range, qc, r, rc, s, th, t, loose, range_ratio)
            if prior is not None:
                near = prior.query(t, k=1)[0] <= prior_radius_m
                s, th, t, n, res = s[near], th[near], t[near], n[near], res[near]
            top = np.lexsort((res, -n))[:top_k]
            cand_n.append(n[top]); cand_res.append(res[top]); cand_s.append(s[top])
            cand_th.append(th[top]); cand_t.append(t[top])
        n_hyp += len(aa)
        if n_hyp >= max_hyp:
            break
    if not cand_n:
        return None
    n, res = np.concatenate(cand_n), np.concatenate(cand_res)
    s_all, th_all, t_all = np.concatenate(cand_s), np.concatenate(cand_th), np.concatenate(cand_t)
    best = None
    for w in np.lexsort((res, -n))[:top_k]:
        _, _, match, inl = _score(q_bear, q_range, qc, r, rc, s_all[w:w + 1], th_all[w:w + 1], t_all[w:w + 1],
                                  loose, range_ratio)
        pairs_in = [(k, int(match[0, k])) for k in range(m) if inl[0, k]]
        x, y, theta, sc = _refine(q_bear, q_range, r, pairs_in, t_all[w], th_all[w], s_all[w])
        n2, res2, match2, inl2 = _score(q_bear, q_range, qc, r, rc, np.array([sc]), np.array([theta]),
                                        np.array([[x, y]]), tight, range_ratio)
        key = (int(n2[0]), -float(res2[0]))
        if best is None or key > best[0]:
            inl_pairs = [(k, int(match2[0, k])) for k in range(m) if inl2[0, k]]
            best = (key, x, y, theta, inl_pairs)
    if best is None:  # every hypothesis fell outside the camera prior
        return None
    _, x, y, theta, inl_pairs = best
    return Pose(x, y, theta, inl_pairs, len(inl_pairs) / m)


def _refine(q_bear, q_range, r, pairs, t, theta, s):
    if len(pairs) < 2:
        return float(t[0]), float(t[1]), float(geo.wrap_angle(theta)), float(s)
    qi = np.array([p[0] for p in pairs])
    ri = np.array([p[1] for p in pairs])

    def resid(p):
        rel = r[ri] - p[:2]
        b = np.arctan2(rel[:, 1], rel[:, 0]) - p[2]
        rng = np.linalg.norm(rel, axis=1)
        # bearings carry the weight; ranges only keep the solution from drifting along rays
        return np.concatenate([geo.wrap_angle(b - q_bear[qi]), 0.05 * (np.log(rng + 1e-9) - p[3] - np.log(q_range[qi] + 1e-9))])

    p0 = np.array([t[0], t[1], theta, np.log(max(s, 1e-9))])  # scale as a log: stays positive
    sol = least_squares(resid, p0, loss="soft_l1", f_scale=0.02)
    return float(sol.x[0]), float(sol.x[1]), float(geo.wrap_angle(sol.x[2])), float(np.exp(sol.x[3]))
