"""Compiled (numba) loops of the likelihood ratio against chance (:mod:`flatlandia.solver.likelihood`).

Two loops: the local density of each map object's class (:func:`class_density`, once per map) and
the log-likelihood ratio of poses (:func:`pose_llr`): every map object in the camera's field of view
and range that no detection explains costs log(1 - p_d), every detection explained by a same-class
object gains its bearing and range likelihood against the chance that an object of its class lies
there at random. Kept apart from ``solver.kernels`` so that the single-frame kernels and their
numba cache are untouched.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

_LOG_2PI = math.log(2.0 * math.pi)
#: the columns of :func:`pose_llr`'s parts: the explained detections' total and the missed objects'
#: (they sum to the ratio), then the explained total's terms
PARTS = ("explained", "missed", "bearing", "range", "class_density", "chance_range", "detection")


class LikelihoodTerms(NamedTuple):
    """The fitted model as :func:`pose_llr` reads it (:class:`flatlandia.solver.likelihood.LikelihoodModel`)."""

    metric: bool  # GT (metre) local map: position residuals; else bearing and log-range residuals
    range_edges: np.ndarray  # (B + 1,) metres, edges of the range bins (last: inf)
    bearing_sigma: np.ndarray  # (B,) rad, per range bin
    log_range_sigma: np.ndarray  # (B,) per range bin
    position_sigma: float  # metres (GT maps)
    fov_half: float  # rad: the field of view is |bearing| <= fov_half
    max_range: float  # metres: objects farther are not in view
    bear_edges: np.ndarray  # (A + 1,) rad, edges of the |bearing| bins of p_d
    intercept: float  # p_d given the views near the pose: logit = intercept + class + range + bearing + views
    cls_logit: np.ndarray  # (K,)
    range_logit: np.ndarray  # (B,)
    bear_logit: np.ndarray  # (A,)
    share_w: float  # weight of the kernel-weighted share of nearby views that saw the object
    nocam_w: float  # weight of the share of the kernel that no view fills
    intercept0: float  # the marginal p_d (no views): the chance hypothesis' detection rate
    cls_logit0: np.ndarray
    range_logit0: np.ndarray
    bear_logit0: np.ndarray
    view_floor: float  # pseudo-weight of "no view" in the share's denominator


@njit(cache=True)
def class_density(x, y, cls, radius):
    """(N,) log of the density (per m^2) of each object's class within ``radius`` of it, the
    object itself counted (so never below one object per disc)."""
    n = x.shape[0]
    out = np.empty(n)
    order = np.argsort(cls)
    r2 = radius * radius
    area = math.pi * r2
    start = 0
    while start < n:
        end = start
        while end < n and cls[order[end]] == cls[order[start]]:
            end += 1
        for a in range(start, end):
            ia = order[a]
            cnt = 0
            for b in range(start, end):
                ib = order[b]
                dx = x[ib] - x[ia]
                dy = y[ib] - y[ia]
                if dx * dx + dy * dy <= r2:
                    cnt += 1
            out[ia] = math.log(cnt / area)
        start = end
    return out


@njit(cache=True, inline="always")
def _bin(edges, v):
    """Index of the bin of ``edges`` holding ``v`` (clamped to the first and last bins)."""
    nb = edges.shape[0] - 1
    for b in range(nb):
        if v < edges[b + 1]:
            return b
    return nb - 1


@njit(cache=True, inline="always")
def _sigmoid(z):
    if z >= 0:
        return 1.0 / (1.0 + math.exp(-z))
    e = math.exp(z)
    return e / (1.0 + e)


@njit(cache=True, inline="always")
def _detection(model, k, rng, bear, share, nocam):
    """(p_d, p_d0) of an object of class ``k`` at range ``rng`` and |bearing| ``bear``: given the
    views near the pose (``share`` of them saw it, ``nocam`` of the kernel empty), and without."""
    rb = _bin(model.range_edges, rng)
    ab = _bin(model.bear_edges, bear)
    z = (
        model.intercept
        + model.cls_logit[k]
        + model.range_logit[rb]
        + model.bear_logit[ab]
        + model.share_w * share
        + model.nocam_w * nocam
    )
    z0 = model.intercept0 + model.cls_logit0[k] + model.range_logit0[rb] + model.bear_logit0[ab]
    return min(max(_sigmoid(z), 1e-6), 1.0 - 1e-6), min(max(_sigmoid(z0), 1e-6), 1.0 - 1e-6)


@njit(cache=True)
def pose_llr(
    tx,
    ty,
    theta,
    s,
    chance_log_s2,
    query,
    cands,
    map_x,
    map_y,
    map_cls,
    log_density,
    cam_w,
    cam_j,
    seen_ptr,
    seen_idx,
    model,
):
    """Log-likelihood ratio against chance of C poses (``tx``, ``ty``, ``theta``, scale ``s``).

    ``query`` (:class:`~flatlandia.solver.kernels.QueryTerms`) and ``cands`` (its same-class
    candidates, rows of the map) as the scoring kernels read them; ``map_*`` every object the pose
    may see (the candidates' rows), ``log_density`` their class density (:func:`class_density`);
    ``cam_w``/``cam_j`` (C, k): kernel weights and indices of the views near each pose (weight 0:
    none), view p saw map rows ``seen_idx[seen_ptr[p]:seen_ptr[p + 1]]``; ``chance_log_s2`` (C,):
    the log of the squared scale the chance hypothesis takes (it does not know the pose's). Returns
    (C,) the ratio, (C, M) the map row each detection is explained by (-1: clutter) and (C, 7) its
    parts (:data:`PARTS`).

    Over 100 lines: one compiled loop per pose (the missed objects in view, then every detection's
    two best explanations, then the greedy one-to-one assignment) over scratch arrays it reuses;
    split into calls, each would pass them all.
    """
    n_hyp = tx.shape[0]
    m = query.bear.shape[0]
    n = map_x.shape[0]
    cand_x, cand_y, cand_idx, ptr = cands
    llr = np.zeros(n_hyp)
    parts = np.zeros((n_hyp, 7))
    comp1 = np.zeros((m, 5))
    comp2 = np.zeros((m, 5))
    comp = np.zeros(5)
    match = np.full((n_hyp, m), -1, np.int64)
    inview = np.zeros(n, np.bool_)
    share = np.zeros(n)
    best1 = np.empty(m)
    best2 = np.empty(m)
    j1 = np.empty(m, np.int64)
    j2 = np.empty(m, np.int64)
    taken = np.zeros(n, np.bool_)
    order = np.empty(m, np.int64)
    r2max = model.max_range * model.max_range
    for c in range(n_hyp):
        cs, sn = math.cos(theta[c]), math.sin(theta[c])
        # the views near the pose: what share of them (kernel-weighted) saw each object
        wsum = 0.0
        for a in range(cam_w.shape[1]):
            wsum += cam_w[c, a]
        den = wsum + model.view_floor
        nocam = model.view_floor / den
        for a in range(cam_w.shape[1]):
            w = cam_w[c, a]
            if w > 0.0:
                v = cam_j[c, a]
                for u in range(seen_ptr[v], seen_ptr[v + 1]):
                    share[seen_idx[u]] += w / den
        # every object in view (a quick range test first) and its detection probability
        miss = 0.0
        for j in range(n):
            taken[j] = False
            inview[j] = False
            rx = map_x[j] - tx[c]
            ry = map_y[j] - ty[c]
            if rx * rx + ry * ry > r2max:
                continue
            lx = cs * rx + sn * ry
            if lx <= 0.0:
                continue
            ly = cs * ry - sn * rx
            bear = abs(math.atan2(ly, lx))
            if bear > model.fov_half:
                continue
            inview[j] = True
            miss += math.log(
                1.0 - _detection(model, map_cls[j], math.sqrt(lx * lx + ly * ly), bear, share[j], nocam)[0]
            )
        # every detection: its best two same-class explanations
        for q in range(m):
            best1[q] = 0.0
            best2[q] = 0.0
            j1[q] = -1
            j2[q] = -1
            for p in range(ptr[q], ptr[q + 1]):
                j = cand_idx[p]
                rx = cand_x[p] - tx[c]
                ry = cand_y[p] - ty[c]
                lx = cs * rx + sn * ry
                ly = cs * ry - sn * rx
                if lx <= 0.0:
                    continue
                rng = math.sqrt(lx * lx + ly * ly)
                rb = _bin(model.range_edges, rng)
                if query.metric:
                    sp = model.position_sigma
                    ex = (lx - query.qx[q]) / sp
                    ey = (ly - query.qy[q]) / sp
                    fit = -0.5 * (ex * ex + ey * ey) - 2.0 * math.log(sp) - _LOG_2PI
                    ll = fit - log_density[j]
                    comp[0], comp[1], comp[2], comp[3] = fit, 0.0, -log_density[j], 0.0
                else:
                    sb = model.bearing_sigma[rb]
                    sr = model.log_range_sigma[rb]
                    eb = math.atan2(ly, lx) - query.bear[q]
                    eb = (eb + math.pi) % (2.0 * math.pi) - math.pi
                    if abs(eb) > 12.0 * sb:
                        continue
                    r_obs = s[c] * query.range_eps[q]
                    er = math.log((rng + s[c] * query.eps) / r_obs) / sr
                    fit = -0.5 * (eb / sb) ** 2 - math.log(sb) - 0.5 * _LOG_2PI
                    fr = -0.5 * er * er - math.log(sr) - 0.5 * _LOG_2PI
                    r2 = 2.0 * math.log(query.range_eps[q]) + chance_log_s2[c]
                    ll = fit + fr - log_density[j] - r2
                    comp[0], comp[1], comp[2], comp[3] = fit, fr, -log_density[j], -r2
                pdj, pd0j = _detection(model, map_cls[j], rng, abs(math.atan2(ly, lx)), share[j], nocam)
                comp[4] = math.log(pdj) - math.log(pd0j)
                if inview[j]:
                    comp[4] -= math.log(1.0 - pdj)
                ll += comp[4]
                if ll > best1[q]:
                    best2[q], j2[q] = best1[q], j1[q]
                    best1[q], j1[q] = ll, j
                    comp2[q] = comp1[q]
                    comp1[q] = comp
                elif ll > best2[q]:
                    best2[q], j2[q] = ll, j
                    comp2[q] = comp
        # each object explains at most one detection: the strongest detections choose first
        for q in range(m):
            order[q] = q
        for a in range(1, m):
            v = order[a]
            b = a - 1
            while b >= 0 and best1[order[b]] < best1[v]:
                order[b + 1] = order[b]
                b -= 1
            order[b + 1] = v
        gain = 0.0
        for a in range(m):
            q = order[a]
            if j1[q] >= 0 and not taken[j1[q]]:
                taken[j1[q]] = True
                match[c, q] = j1[q]
                gain += best1[q]
                parts[c, 2:] += comp1[q]
            elif j2[q] >= 0 and not taken[j2[q]]:
                taken[j2[q]] = True
                match[c, q] = j2[q]
                gain += best2[q]
                parts[c, 2:] += comp2[q]
        llr[c] = gain + miss
        parts[c, 0] = gain
        parts[c, 1] = miss
        for a in range(cam_w.shape[1]):  # reset the shares this pose touched
            if cam_w[c, a] > 0.0:
                v = cam_j[c, a]
                for u in range(seen_ptr[v], seen_ptr[v + 1]):
                    share[seen_idx[u]] = 0.0
    return llr, match, parts
