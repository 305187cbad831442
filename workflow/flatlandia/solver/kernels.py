"""Compiled (numba) scoring loops of the geometric solver.

Why: scoring every hypothesis against every same-class candidate as padded (C, M, K) numpy arrays
spent most of a whole-map query (docs/measurements.md, "Code paths") building temporaries for candidates that a
bearing test rejects at once. Here each (hypothesis, query object) walks only its own class's
candidates and skips a candidate as soon as its bearing cost alone cannot beat the best so far or
the inlier cap; the result is the same MSAC data term, inlier mask and matches as the numpy
reference ``scoring.padded_costs`` (tested against it).

Candidates are given flat: object ``k``'s candidates are ``cand_x/cand_y/cand_idx[ptr[k]:ptr[k+1]]``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from flatlandia.solver.noise import bearing_error, range_bin

_QUARTER_PI = math.pi / 4.0


class Candidates(NamedTuple):
    """Same-class candidates of every query object, flat: object ``k``'s are ``[ptr[k]:ptr[k+1]]``."""

    x: np.ndarray  # (N,) candidate positions
    y: np.ndarray
    idx: np.ndarray  # (N,) int64 rows of the reference map
    ptr: np.ndarray  # (M + 1,) int64 offsets per query object


class QueryTerms(NamedTuple):
    """The query's observations and noise, as the scoring and refinement kernels read them."""

    metric: bool  # GT (metre) local map, else an unscaled depth map
    qx: np.ndarray  # (M,) local positions
    qy: np.ndarray
    bear: np.ndarray  # (M,) bearings (rad)
    range_eps: np.ndarray  # (M,) range + eps (small-range guard)
    eps: float
    #: depth maps: the noise model per range bin of the candidate (:class:`flatlandia.solver.noise.NoiseTerms`)
    range_edges: np.ndarray  # (B + 1,) metres
    bearing_sigma: np.ndarray  # (B,) rad
    log_range_sigma: np.ndarray  # (B,)
    position_sigma: float  # metric maps (m)


class PriorTerms(NamedTuple):
    """Prior rows of the refinement (depth maps); a weight of 0 switches a prior off."""

    cam: np.ndarray  # (C, 2) the prior camera each hypothesis is tied to
    weight: float
    sigma: float
    head: np.ndarray  # (C,) its heading (rad)
    head_sigma: float  # 0: no heading prior
    scale_mu: float
    scale_sd: float
    scale_weight: float


@njit(cache=True, inline="always")
def _record(c, k, best, bj, tau2, inl, match, cand_idx, ptr):
    """Book object ``k``'s best candidate for hypothesis ``c``: inlier flag, match (its candidate
    ``bj``, 0 when it has none) and its capped cost, returned."""
    match[c, k] = cand_idx[bj] if ptr[k + 1] > ptr[k] else 0
    if best < tau2:
        inl[c, k] = True
        return best
    return tau2


@njit(cache=True, fastmath=False)
def score_depth(tx, ty, theta, s, query, cands, tau2):
    """Depth (unscaled) local maps: the wrapped bearing error (:func:`~flatlandia.solver.noise.bearing_error`)
    over its sigma plus the log-range error at scale ``s`` over its sigma, both of the candidate's
    range bin (the noise model). Returns the capped data cost (C,), inliers (C, M), matches (C, M)."""
    q_bear, q_range_eps, eps_q = query.bear, query.range_eps, query.eps
    edges, sb, sr = query.range_edges, query.bearing_sigma, query.log_range_sigma
    edges2 = edges * edges
    sb_max2 = sb.max() ** 2
    cand_x, cand_y, cand_idx, ptr = cands
    n_hyp, m = tx.shape[0], q_bear.shape[0]
    total = np.zeros(n_hyp)
    inl = np.zeros((n_hyp, m), np.bool_)
    match = np.zeros((n_hyp, m), np.int64)
    for c in range(n_hyp):
        acc = 0.0
        for k in range(m):
            wb = theta[c] + q_bear[k]
            ux, uy = math.cos(wb), math.sin(wb)
            lim = tau2
            best = math.inf
            bj = ptr[k]
            for p in range(ptr[k], ptr[k + 1]):
                rx = cand_x[p] - tx[c]
                ry = cand_y[p] - ty[c]
                along = ux * rx + uy * ry
                if along <= 0.0:
                    continue
                across = ux * ry - uy * rx
                # a lower bound of the angle, without an arctangent: atan(t) >= pi/4 min(t, 1); first
                # at the loosest sigma, then at the sigma of the range's bin (squared edges: no root)
                lb = _QUARTER_PI * min(abs(across) / along, 1.0)
                if lb * lb >= lim * sb_max2:
                    continue
                r2 = rx * rx + ry * ry
                b = range_bin(edges2, r2)
                if lb * lb >= lim * sb[b] * sb[b]:
                    continue
                rr = math.sqrt(r2)
                tb = bearing_error(along, across) / sb[b]
                eb = tb * tb
                if eb >= lim:
                    continue
                dr = math.log((rr + s[c] * eps_q) / (s[c] * q_range_eps[k])) / sr[b]
                cst = eb + dr * dr
                if cst < best:
                    best = cst
                    bj = p
                    lim = min(lim, cst)
            acc += _record(c, k, best, bj, tau2, inl, match, cand_idx, ptr)
        total[c] = acc
    return total, inl, match


@njit(cache=True, fastmath=False)
def score_metric(tx, ty, theta, query, cands, tau2):
    """Metric (GT) local maps: squared position error in the camera frame over ``sp``**2."""
    qx, qy, sp = query.qx, query.qy, query.position_sigma
    cand_x, cand_y, cand_idx, ptr = cands
    n_hyp, m = tx.shape[0], qx.shape[0]
    total = np.zeros(n_hyp)
    inl = np.zeros((n_hyp, m), np.bool_)
    match = np.zeros((n_hyp, m), np.int64)
    inv = 1.0 / (sp * sp)
    for c in range(n_hyp):
        cs, sn = math.cos(theta[c]), math.sin(theta[c])
        acc = 0.0
        for k in range(m):
            best = math.inf
            bj = ptr[k]
            for p in range(ptr[k], ptr[k + 1]):
                rx = cand_x[p] - tx[c]
                ry = cand_y[p] - ty[c]
                dx = cs * rx + sn * ry - qx[k]
                dy = cs * ry - sn * rx - qy[k]
                cst = (dx * dx + dy * dy) * inv
                if cst < best:
                    best = cst
                    bj = p
            acc += _record(c, k, best, bj, tau2, inl, match, cand_idx, ptr)
        total[c] = acc
    return total, inl, match


@njit(cache=True)
def _solve_small(H, g, n):
    """x with H x = g for an n x n (n <= 4) system by Gaussian elimination with partial pivoting;
    all zeros when H is singular."""
    A = np.empty((n, n + 1))
    for i in range(n):
        for j in range(n):
            A[i, j] = H[i, j]
        A[i, n] = g[i]
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(A[r, col]) > abs(A[piv, col]):
                piv = r
        if abs(A[piv, col]) < 1e-300:
            return np.zeros(n)
        if piv != col:
            for j in range(n + 1):
                A[col, j], A[piv, j] = A[piv, j], A[col, j]
        for r in range(col + 1, n):
            f = A[r, col] / A[col, col]
            for j in range(col, n + 1):
                A[r, j] -= f * A[col, j]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        acc = A[i, n]
        for j in range(i + 1, n):
            acc -= A[i, j] * x[j]
        x[i] = acc / A[i, i]
    return x


@njit(cache=True)
def damped_step(H, g, p, c, npar):
    """One Gauss-Newton step of hypothesis ``c`` (row ``c`` of ``p``, its first ``npar`` parameters)
    from its normal equations ``H`` x = ``g``, a little Levenberg damping on the diagonal; False
    when the step is not finite (``p`` unchanged) or below 1e-10 (converged): the caller stops."""
    for a in range(npar):
        H[a, a] += 1e-6
    step = _solve_small(H, g, npar)
    big = 0.0
    for a in range(npar):
        if not math.isfinite(step[a]):
            return False
        big = max(big, abs(step[a]))
    for a in range(npar):
        p[c, a] -= step[a]
    return big >= 1e-10


@njit(cache=True)
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _match_rows(H, g, J, p, c, R, inl, query, npar):
    """Add the soft-L1 weighted rows of hypothesis ``c``'s matches to the normal equations: bearing
    and log-range rows (depth maps, sigmas of the match's range bin) or the two position rows in
    the camera frame (metric maps)."""
    cs, sn = math.cos(p[c, 2]), math.sin(p[c, 2])
    sc = math.exp(p[c, 3])
    sp, eps = query.position_sigma, query.eps
    for k in range(R.shape[1]):
        if not inl[c, k]:
            continue
        rx = R[c, k, 0] - p[c, 0]
        ry = R[c, k, 1] - p[c, 1]
        for row in range(2):
            for a in range(4):
                J[a] = 0.0
            if query.metric:
                lx = cs * rx + sn * ry
                ly = -sn * rx + cs * ry
                if row == 0:
                    e = (lx - query.qx[k]) / sp
                    J[0], J[1], J[2] = -cs / sp, -sn / sp, ly / sp
                else:
                    e = (ly - query.qy[k]) / sp
                    J[0], J[1], J[2] = sn / sp, -cs / sp, -lx / sp
            else:
                rho2 = max(rx * rx + ry * ry, 1e-12)
                rho = math.sqrt(rho2)
                b = range_bin(query.range_edges, rho)
                sb, sr = query.bearing_sigma[b], query.log_range_sigma[b]
                if row == 0:
                    e = _wrap(math.atan2(ry, rx) - p[c, 2] - query.bear[k]) / sb
                    J[0], J[1], J[2] = ry / rho2 / sb, -rx / rho2 / sb, -1.0 / sb
                else:
                    gg = 1.0 / (rho + sc * eps)
                    e = (math.log(rho + sc * eps) - math.log(sc * query.range_eps[k])) / sr
                    J[0], J[1] = -rx / rho * gg / sr, -ry / rho * gg / sr
                    J[3] = (sc * eps * gg - 1.0) / sr
            w = 1.0 / math.sqrt(1.0 + e * e)
            for a in range(npar):
                g[a] += w * J[a] * e
                for b in range(npar):
                    H[a, b] += w * J[a] * J[b]


@njit(cache=True)
def _prior_rows(H, g, p, c, priors):
    """Add the prior rows of hypothesis ``c`` (position, heading, log scale); they share one
    soft-L1 weight on their total."""
    ex0 = ex1 = ex2 = ex3 = 0.0
    tot = 0.0
    if priors.weight > 0:
        wpr = math.sqrt(priors.weight)
        ex0 = wpr * (p[c, 0] - priors.cam[c, 0]) / priors.sigma
        ex1 = wpr * (p[c, 1] - priors.cam[c, 1]) / priors.sigma
        tot += ex0 * ex0 + ex1 * ex1
        if priors.head_sigma > 0:
            ex2 = wpr * _wrap(p[c, 2] - priors.head[c]) / priors.head_sigma
            tot += ex2 * ex2
    if priors.scale_weight > 0:
        ex3 = math.sqrt(priors.scale_weight) * (p[c, 3] - priors.scale_mu) / priors.scale_sd
        tot += ex3 * ex3
    w = 1.0 / math.sqrt(1.0 + tot)
    if priors.weight > 0:
        jp = math.sqrt(priors.weight) / priors.sigma
        H[0, 0] += w * jp * jp
        H[1, 1] += w * jp * jp
        g[0] += w * jp * ex0
        g[1] += w * jp * ex1
        if priors.head_sigma > 0:
            jh = math.sqrt(priors.weight) / priors.head_sigma
            H[2, 2] += w * jh * jh
            g[2] += w * jh * ex2
    if priors.scale_weight > 0:
        js = math.sqrt(priors.scale_weight) / priors.scale_sd
        H[3, 3] += w * js * js
        g[3] += w * js * ex3


@njit(cache=True)
def refine_gauss_newton(p, R, inl, query, priors, iters):
    """Robust Gauss-Newton (soft-L1 IRLS, analytic Jacobians) of each hypothesis on its matches.

    ``p`` (C, 4): x, y, theta, log scale (updated in place); ``R`` (C, M, 2) matched candidates;
    ``inl`` (C, M) which matches count; ``query`` (:class:`QueryTerms`): bearing residuals (1/sb)
    and log-range residuals (1/sr) of the match's range bin for depth maps, positions in the camera frame (1/sp, 3
    parameters) for metric maps; ``priors`` (:class:`PriorTerms`, depth maps only). Stops a
    hypothesis when its step is below 1e-10.
    """
    n_hyp, m = R.shape[0], R.shape[1]
    npar = 3 if query.metric else 4
    J = np.zeros(4)
    for c in range(n_hyp):
        n_in = 0
        for k in range(m):
            if inl[c, k]:
                n_in += 1
        if n_in < 2:
            continue
        for _ in range(iters):
            H = np.zeros((4, 4))
            g = np.zeros(4)
            _match_rows(H, g, J, p, c, R, inl, query, npar)
            if not query.metric:
                _prior_rows(H, g, p, c, priors)
            if not damped_step(H, g, p, c, npar):
                break
    return p


@njit(cache=True)
def covis_counts(d, j, seen, match, inl, radius):
    """(C,) the most inlier matches that one prior camera within ``radius`` saw: ``d``/``j`` (C, k)
    distances and indices of the nearest prior cameras, ``seen`` (P, N), ``match``/``inl`` (C, M)."""
    n_hyp, kk = j.shape
    m = match.shape[1]
    out = np.zeros(n_hyp, np.int64)
    for c in range(n_hyp):
        best = 0
        for a in range(kk):
            if not d[c, a] <= radius:
                continue
            cam = j[c, a]
            cnt = 0
            for k in range(m):
                if inl[c, k] and seen[cam, match[c, k]]:
                    cnt += 1
            best = max(best, cnt)
        out[c] = best
    return out


class CoSeen(NamedTuple):
    """Which candidates some prior camera saw together: a matrix and, per candidate, the list."""

    pair: np.ndarray  # (N, N) bool
    ptr: np.ndarray  # (N + 1,) int64: candidate a's co-seen candidates are idx[ptr[a]:ptr[a + 1]]
    idx: np.ndarray  # int64


@njit(cache=True)
def coseen_pairs(cam, obj, n):
    """The :class:`CoSeen` fields of objects ``a`` and ``b`` seen by one camera (``a`` with itself
    when seen at all); ``cam``/``obj`` list who saw what, grouped by camera (as ``np.nonzero`` of a
    (P, n) matrix gives them)."""
    pair = np.zeros((n, n), np.bool_)
    start = 0
    for end in range(1, len(cam) + 1):
        if end == len(cam) or cam[end] != cam[start]:
            for u in range(start, end):
                for v in range(start, end):
                    pair[obj[u], obj[v]] = True
            start = end
    ptr = np.zeros(n + 1, np.int64)
    for a in range(n):
        ptr[a + 1] = ptr[a] + pair[a].sum()
    idx = np.empty(ptr[n], np.int64)
    for a in range(n):
        h = ptr[a]
        for b in range(n):
            if pair[a, b]:
                idx[h] = b
                h += 1
    return pair, ptr, idx


@njit(cache=True)
def _member(cands, n):
    """(n,) bool mask of the rows in ``cands``."""
    out = np.zeros(n, np.bool_)
    for a in cands:
        out[a] = True
    return out


@njit(cache=True)
def _candidate_triples(ca, cb, cc, co, use_co):
    """(H, 3) triples of distinct candidates from ``ca`` x ``cb`` x ``cc``; with ``use_co`` only those
    whose three pairs were seen together (:class:`CoSeen`), walked along the co-seen lists."""
    pair, ptr, idx = co
    if not use_co:
        out = np.empty((len(ca) * len(cb) * len(cc), 3), np.int64)
        h = 0
        for a in ca:
            for b in cb:
                for c in cc:
                    if b != a and c != a and c != b:
                        out[h, 0], out[h, 1], out[h, 2] = a, b, c
                        h += 1
        return out[:h]
    n = pair.shape[0]
    in_b, in_c = _member(cb, n), _member(cc, n)
    total = 0
    for a in ca:
        nb = nc = 0
        for u in range(ptr[a], ptr[a + 1]):
            nb += in_b[idx[u]]
            nc += in_c[idx[u]]
        total += nb * nc
    out = np.empty((total, 3), np.int64)
    h = 0
    for a in ca:
        for u in range(ptr[a], ptr[a + 1]):
            b = idx[u]
            if b == a or not in_b[b]:
                continue
            for v in range(ptr[a], ptr[a + 1]):
                c = idx[v]
                if c != a and c != b and in_c[c] and pair[b, c]:
                    out[h, 0], out[h, 1], out[h, 2] = a, b, c
                    h += 1
    return out[:h]


@njit(cache=True)
def triple_resections(ca, cb, cc, co, use_co, rx, ry, bi, bj, bk, ri, rj, rk, eps, min_scale, max_scale, metric):
    """3-bearing resections of query bearings (bi, bj, bk) (ranges ri, rj, rk + ``eps`` give the
    scale) onto every triple of distinct candidates from ``ca`` x ``cb`` x ``cc`` (with ``use_co``,
    only triples seen together pairwise, ``co`` a :class:`CoSeen`). See ``hypotheses.triple_hypotheses``
    for the algebra. Returns t (H, 2), theta (H,), scale (H,)."""
    abc = _candidate_triples(ca, cb, cc, co, use_co)
    n = abc.shape[0]
    t = np.empty((n, 2))
    th = np.empty(n)
    sc = np.empty(n)
    e_j = complex(math.cos(bj - bi), -math.sin(bj - bi))
    e_k = complex(math.cos(bk - bi), -math.sin(bk - bi))
    lq = (math.log(ri + eps) + math.log(rj + eps) + math.log(rk + eps)) / 3.0
    h = 0
    for w in range(n):
        a, b, c = abc[w, 0], abc[w, 1], abc[w, 2]
        A, B, C = complex(rx[a], ry[a]), complex(rx[b], ry[b]), complex(rx[c], ry[c])
        k1 = e_j * (B - A)
        k2 = e_k * (C - A)
        a11, a12, b1 = k1.imag, k1.real, -e_j.imag
        a21, a22, b2 = k2.imag, k2.real, -e_k.imag
        det = a11 * a22 - a12 * a21
        if abs(det) <= 1e-12:
            continue
        u = complex((b1 * a22 - a12 * b2) / det, (a11 * b2 - b1 * a21) / det)
        if abs(u) <= 1e-12:
            continue
        z = A - 1.0 / u
        theta = math.atan2((A - z).imag, (A - z).real) - bi
        zb, zc = B - z, C - z
        if abs(_wrap(math.atan2(zb.imag, zb.real) - theta - bj)) >= 1e-3:
            continue
        if abs(_wrap(math.atan2(zc.imag, zc.real) - theta - bk)) >= 1e-3:
            continue
        s = 1.0
        if not metric:
            ld = (math.log(abs(A - z) + 1e-9) + math.log(abs(zb) + 1e-9) + math.log(abs(zc) + 1e-9)) / 3.0
            s = math.exp(ld - lq)
            if s < min_scale or s > max_scale:
                continue
        t[h, 0], t[h, 1] = z.real, z.imag
        th[h] = _wrap(theta)
        sc[h] = s
        h += 1
    return t[:h], th[:h], sc[:h]


@njit(cache=True)
def pair_fits(ca, cb, co, use_co, rx, ry, qix, qiy, dqx, dqy, metric, len_tol, min_scale, max_scale):
    """2-point fits of a query pair (object i at (qix, qiy), offset (dqx, dqy) to object j) onto every
    ordered pair of distinct candidates (a in ``ca``, b in ``cb``; with ``use_co`` only pairs seen
    together, ``co`` a :class:`CoSeen`). Returns t (H, 2), theta (H,), scale (H,)."""
    n = len(ca) * len(cb)
    t = np.empty((n, 2))
    th = np.empty(n)
    sc = np.empty(n)
    lq = math.hypot(dqx, dqy)
    aq = math.atan2(dqy, dqx)
    h = 0
    for a in ca:
        for b in cb:
            if a == b or (use_co and not co.pair[a, b]):
                continue
            drx, dry = rx[b] - rx[a], ry[b] - ry[a]
            lr = math.hypot(drx, dry)
            if metric:
                if abs(lr - lq) > len_tol:
                    continue
                s = 1.0
            else:
                s = lr / lq
                if s < min_scale or s > max_scale:
                    continue
            theta = math.atan2(dry, drx) - aq
            c, sn = math.cos(theta), math.sin(theta)
            t[h, 0] = rx[a] - s * (c * qix - sn * qiy)
            t[h, 1] = ry[a] - s * (sn * qix + c * qiy)
            th[h] = _wrap(theta)
            sc[h] = s
            h += 1
    return t[:h], th[:h], sc[:h]


@njit(cache=True)
def distinct_in_order(order, tx, ty, theta, top_k, radius, turn):
    """The first ``top_k`` of ``order`` skipping any within ``radius`` and ``turn`` (rad) of one
    already chosen (:func:`flatlandia.solver.hypotheses.distinct_best`)."""
    chosen = np.empty(min(top_k, len(order)), np.int64)
    n = 0
    two_pi = 2.0 * math.pi
    for w in order:
        if n >= top_k:
            break
        near = False
        for a in range(n):
            v = chosen[a]
            dth = (theta[w] - theta[v] + math.pi) % two_pi - math.pi
            if math.hypot(tx[w] - tx[v], ty[w] - ty[v]) < radius and abs(dth) < turn:
                near = True
                break
        if not near:
            chosen[n] = w
            n += 1
    return chosen[:n]
