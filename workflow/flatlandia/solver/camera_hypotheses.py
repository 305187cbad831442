"""Hypotheses seeded at every prior (training) camera: the complete half of the solver's pool.

Why: the cost-picked pool (:mod:`flatlandia.solver.hypotheses`) holds the dozen poses the MSAC cost
liked best, so the probability normalised over it cannot see a place it never scored (a right pose
generated but cut, or never generated: a third of the depth-map queries, docs/results.md). Every
place a query can be is near some training camera (the prior gate drops the rest), so a hypothesis
at each camera, with the heading the query's bearings vote for against the same-class objects that
camera would see, covers the places the gate allows; refined by the solver's own refinement, the
seeds and the cost-picked pool together are the set the answer's probability is normalised over.

The vote (:func:`vote_headings`, compiled): for camera ``c`` and query object ``i`` of bearing
``b_i``, every same-class candidate ``n`` within ``camera_vote_range_m`` of ``c`` at world bearing ``phi``
votes heading ``phi - b_i``; a vote's support is the number of query objects with a vote within
``camera_vote_tol_deg`` of it, and each camera keeps its ``camera_headings`` best supported (at least
two objects) distinct headings, each with the median range ratio of its supporters as its scale.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from flatlandia.solver import hypotheses, scoring
from flatlandia.solver.priors import Priors
from flatlandia.solver.problem import Problem


@njit(cache=True)
def vote_headings(cams, rx, ry, ptr, idx, bear, q_range, max_range, tol, per_camera, metric):
    """(S, 4) seeds: camera x, y, heading (rad), scale, at most ``per_camera`` per camera of ``cams``
    (P, 2); ``idx[ptr[k]:ptr[k+1]]`` are query object ``k``'s same-class candidates (rows of
    ``rx``/``ry``), ``bear``/``q_range`` its bearing and range (local units)."""
    m = len(bear)
    n_max = 0
    for k in range(m):
        n_max += ptr[k + 1] - ptr[k]
    out = np.zeros((len(cams) * per_camera, 4))
    n_out = 0
    ang = np.empty(n_max)
    obj = np.empty(n_max, np.int64)
    ratio = np.empty(n_max)
    support = np.empty(n_max, np.int64)
    taken = np.empty(per_camera)
    hit = np.zeros(m, np.bool_)
    best_d = np.empty(m)
    best_r = np.empty(m)
    best_a = np.empty(m)
    two_pi = 2.0 * math.pi
    for c in range(len(cams)):
        cx, cy = cams[c, 0], cams[c, 1]
        v = 0
        for k in range(m):
            for e in range(ptr[k], ptr[k + 1]):
                n = idx[e]
                dx, dy = rx[n] - cx, ry[n] - cy
                d = math.sqrt(dx * dx + dy * dy)
                if d < 1e-6 or d > max_range:
                    continue
                a = math.atan2(dy, dx) - bear[k]
                ang[v] = a - two_pi * math.floor(a / two_pi)
                obj[v] = k
                ratio[v] = d / max(q_range[k], 1e-9)
                v += 1
        if v == 0:
            continue
        # support of each vote: the query objects with a vote within tol of it
        # sorted by angle, each vote's neighbours within tol are a short circular window
        order = np.argsort(ang[:v])
        ang[:v] = ang[:v][order]
        obj[:v] = obj[:v][order]
        ratio[:v] = ratio[:v][order]
        for w in range(v):
            hit[:] = False
            hit[obj[w]] = True
            count = 1
            for step in (1, -1):
                u = w
                for _ in range(v - 1):
                    u = (u + step) % v
                    da = abs(ang[u] - ang[w])
                    if min(da, two_pi - da) > tol:
                        break
                    if not hit[obj[u]]:
                        hit[obj[u]] = True
                        count += 1
            support[w] = count
        n_taken = 0
        for _ in range(per_camera):
            best, best_w = 1, -1
            for w in range(v):
                if support[w] <= best:
                    continue
                far = True
                for t in range(n_taken):
                    da = abs(ang[w] - taken[t])
                    if min(da, two_pi - da) < 2.0 * tol:
                        far = False
                        break
                if far:
                    best, best_w = support[w], w
            if best_w < 0:
                break
            # the closest vote of each supporting object: the heading's circular mean, the scale's median
            for k in range(m):
                best_d[k] = 1e9
            for u in range(v):
                da = ang[u] - ang[best_w]
                da = da - two_pi * math.floor((da + math.pi) / two_pi)
                if abs(da) <= tol and abs(da) < best_d[obj[u]]:
                    best_d[obj[u]] = abs(da)
                    best_a[obj[u]] = da
                    best_r[obj[u]] = ratio[u]
            sa, n_sup = 0.0, 0
            rs = np.empty(m)
            for k in range(m):
                if best_d[k] < 1e9:
                    sa += best_a[k]
                    rs[n_sup] = best_r[k]
                    n_sup += 1
            heading = ang[best_w] + sa / n_sup
            taken[n_taken] = ang[best_w]
            n_taken += 1
            out[n_out, 0] = cx
            out[n_out, 1] = cy
            out[n_out, 2] = heading - two_pi * math.floor((heading + math.pi) / two_pi)
            out[n_out, 3] = 1.0 if metric else np.median(rs[:n_sup])
            n_out += 1
    return out[:n_out]


def seeds(problem: Problem, priors: Priors):
    """(t (S, 2), theta (S,), s (S,), how many were voted) of the seeds at every prior camera (:func:`vote_headings`),
    refined by one cheap round, deduplicated on a 1 m / 2 deg grid (the ``camera_refine_max``
    cheapest by the MSAC cost, 0: all), then refined in full; None
    without prior cameras, with seeding off (``camera_hypotheses``) or when no camera sees two objects
    the query's bearings agree on."""
    cfg = problem.cfg
    if not cfg.camera_hypotheses or priors.tree is None or problem.m < 2:
        return None
    cams = np.ascontiguousarray(priors.tree.data, dtype=float)
    cand = problem.candidates
    raw = vote_headings(
        cams,
        problem.rx,
        problem.ry,
        cand.ptr,
        cand.idx,
        np.ascontiguousarray(problem.q_bear),
        np.ascontiguousarray(problem.q_range),
        float(cfg.camera_vote_range_m),
        math.radians(cfg.camera_vote_tol_deg),
        int(cfg.camera_headings),
        bool(problem.metric),
    )
    if not len(raw):
        return None
    s = np.clip(raw[:, 3], cfg.min_scale, cfg.max_scale)
    t, theta, s = scoring.refine(problem, priors, raw[:, :2], raw[:, 2], s, rounds=1, iters=cfg.camera_cheap_iters)
    cost = scoring.score(problem, priors, t, theta, s)[0]
    ok = np.isfinite(cost) & np.isfinite(t).all(1)
    if not ok.any():
        return None
    t, theta, s, cost = t[ok], theta[ok], s[ok], cost[ok]
    keep = hypotheses.distinct_best(cost, t, theta, cfg.camera_refine_max or len(cost))
    return (*scoring.refine(problem, priors, t[keep], theta[keep], s[keep]), len(raw))
