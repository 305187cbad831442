"""Compiled (numba) loops of the sequence solver (:mod:`flatlandia.solver.sequence`).

Two loops: a frame's depth scale at a pose (:func:`fit_scales`: the median log ratio of the
best-bearing same-class candidates' ranges to the frame's ranges, a 1-D fit that needs no match
yet) and the joint refinement of a sequence (:func:`refine_sequence`: robust Gauss-Newton of the
anchor's pose, every frame's log scale and each companion's odometry slack on the matches of every
frame). Kept apart from ``solver.kernels`` so that the single-frame kernels and their numba cache
are untouched.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from flatlandia.solver.kernels import _wrap, damped_step
from flatlandia.solver.noise import bearing_error, range_bin


@njit(cache=True)
def fit_scales(tx, ty, theta, bear, range_eps, cands, tau2, edges, sb, default):
    """(C,) metres per local unit of one depth frame at poses (``tx``, ``ty``, ``theta``): for each
    object the same-class candidate in front of the camera with the smallest bearing error (the
    wrapped angle, below ``tau2`` in squared sigmas ``sb`` of its range bin of ``edges``) votes
    log(candidate range / object range); the median vote, or ``default`` where no object votes."""
    cand_x, cand_y, _, ptr = cands
    n_hyp, m = tx.shape[0], bear.shape[0]
    out = np.empty(n_hyp)
    votes = np.empty(m)
    for c in range(n_hyp):
        nv = 0
        for k in range(m):
            wb = theta[c] + bear[k]
            ux, uy = math.cos(wb), math.sin(wb)
            best = tau2
            br = -1.0
            for p in range(ptr[k], ptr[k + 1]):
                rx = cand_x[p] - tx[c]
                ry = cand_y[p] - ty[c]
                along = ux * rx + uy * ry
                if along <= 0.0:
                    continue
                rr = math.sqrt(rx * rx + ry * ry)
                tb = bearing_error(along, ux * ry - uy * rx) / sb[range_bin(edges, rr)]
                eb = tb * tb
                if eb < best:
                    best = eb
                    br = rr
            if br > 0.0:
                votes[nv] = math.log(br) - math.log(range_eps[k])
                nv += 1
        out[c] = math.exp(np.median(votes[:nv])) if nv > 0 else default
    return out


class SequenceTerms(NamedTuple):
    """Every frame's observations and the ties between frames, as :func:`refine_sequence` reads them.

    Objects of all frames are concatenated; ``frame[k]`` is object k's frame."""

    frame: np.ndarray  # (M,) int64 frame of each object
    bear: np.ndarray  # (M,) bearings (rad) in their frame
    range_eps: np.ndarray  # (M,) range + eps of their frame
    eps: np.ndarray  # (F,) each frame's small-range guard
    odo: np.ndarray  # (F, 3) each frame's pose in the anchor's camera frame (dx, dy, dtheta); row 0 zeros
    odo_sigma: np.ndarray  # (F, 2) its noise: position (m), heading (rad); row 0 unused
    #: the noise model per range bin of the match (:class:`flatlandia.solver.noise.NoiseTerms`)
    range_edges: np.ndarray
    bearing_sigma: np.ndarray  # (B,) rad
    log_range_sigma: np.ndarray  # (B,)


class SequencePriorTerms(NamedTuple):
    """Prior rows of the joint refinement; a weight of 0 switches one off."""

    cam: np.ndarray  # (C, F, 2) the training camera each frame of each hypothesis is tied to
    head: np.ndarray  # (C, F) its heading (rad)
    cam_weight: float
    cam_sigma: float
    head_sigma: float  # 0: no heading prior
    scale_mu: float
    scale_sd: float
    scale_weight: float
    fix: np.ndarray  # (2,) the anchor's position fix (GPS)
    fix_sigma: float  # 0: no fix
    fix_heading: float  # the anchor's compass heading (rad)
    fix_heading_sigma: float  # 0: none


@njit(cache=True)
def _frame_pose(p, c, f, odo, n_frames):
    """Frame ``f``'s pose (x, y, theta) and d(x, y)/d(anchor theta) for hypothesis ``c``."""
    th0 = p[c, 2]
    cs, sn = math.cos(th0), math.sin(th0)
    dx, dy = odo[f, 0], odo[f, 1]
    x = p[c, 0] + cs * dx - sn * dy
    y = p[c, 1] + sn * dx + cs * dy
    th = th0 + odo[f, 2]
    if f > 0:
        base = 3 + n_frames + 3 * (f - 1)
        x += p[c, base]
        y += p[c, base + 1]
        th += p[c, base + 2]
    return x, y, th, -sn * dx - cs * dy, cs * dx - sn * dy


@njit(cache=True)
def _accumulate(H, g, J, idx, nj, e, w):
    """Add one weighted row (sparse Jacobian ``J[:nj]`` at parameters ``idx[:nj]``) to H and g."""
    for a in range(nj):
        g[idx[a]] += w * J[a] * e
        for b in range(nj):
            H[idx[a], idx[b]] += w * J[a] * J[b]


@njit(cache=True)
def refine_sequence(p, R, inl, terms, priors, iters):
    """Robust Gauss-Newton (soft-L1 IRLS) of C sequence hypotheses on their matches.

    ``p`` (C, 4F): anchor x, y, theta; log scale of each of the F frames; then per companion frame
    (1..F-1) its odometry slack (x, y in the map frame, heading), tied to zero by the odometry's
    noise (updated in place). Frame f's pose is the anchor's composed with ``terms.odo[f]`` plus its
    slack. ``R`` (C, M, 2) matched candidates of every object, ``inl`` (C, M) which count. Rows:
    bearings and log-ranges of every frame (as the single-frame refinement), the odometry slack,
    each frame's scale prior and camera prior (``priors.cam`` / ``head``), and the anchor's fix.

    Over 100 lines: one compiled loop per hypothesis that assembles every row of one sparse normal
    system; split into calls, each would pass the same dozen arrays and scratch buffers back and forth.
    """
    n_hyp, m = R.shape[0], R.shape[1]
    nf = terms.odo.shape[0]
    npar = 4 * nf
    J = np.zeros(8)
    idx = np.zeros(8, np.int64)
    for c in range(n_hyp):
        n_in = 0
        for k in range(m):
            if inl[c, k]:
                n_in += 1
        if n_in < 2:
            continue
        for _ in range(iters):
            H = np.zeros((npar, npar))
            g = np.zeros(npar)
            for k in range(m):
                if not inl[c, k]:
                    continue
                f = terms.frame[k]
                x, y, th, dxt, dyt = _frame_pose(p, c, f, terms.odo, nf)
                ls = 3 + f
                sc = math.exp(p[c, ls])
                rx = R[c, k, 0] - x
                ry = R[c, k, 1] - y
                rho2 = max(rx * rx + ry * ry, 1e-12)
                rho = math.sqrt(rho2)
                rb = range_bin(terms.range_edges, rho)
                sb, sr = terms.bearing_sigma[rb], terms.log_range_sigma[rb]
                base = 3 + nf + 3 * (f - 1)
                for row in range(2):
                    if row == 0:
                        e = _wrap(math.atan2(ry, rx) - th - terms.bear[k]) / sb
                        jx, jy, jt, js = ry / rho2 / sb, -rx / rho2 / sb, -1.0 / sb, 0.0
                    else:
                        gg = 1.0 / (rho + sc * terms.eps[f])
                        e = (math.log(rho + sc * terms.eps[f]) - math.log(sc * terms.range_eps[k])) / sr
                        jx, jy, jt, js = (
                            -rx / rho * gg / sr,
                            -ry / rho * gg / sr,
                            0.0,
                            (sc * terms.eps[f] * gg - 1.0) / sr,
                        )
                    nj = 4
                    idx[0], J[0] = 0, jx
                    idx[1], J[1] = 1, jy
                    idx[2], J[2] = 2, jx * dxt + jy * dyt + jt
                    idx[3], J[3] = ls, js
                    if f > 0:
                        idx[4], J[4] = base, jx
                        idx[5], J[5] = base + 1, jy
                        idx[6], J[6] = base + 2, jt
                        nj = 7
                    _accumulate(H, g, J, idx, nj, e, 1.0 / math.sqrt(1.0 + e * e))
            # odometry slack: each companion's (x, y, heading) offset tied to zero
            for f in range(1, nf):
                base = 3 + nf + 3 * (f - 1)
                for a in range(3):
                    sig = terms.odo_sigma[f, 0] if a < 2 else terms.odo_sigma[f, 1]
                    sig = max(sig, 1e-6)
                    idx[0], J[0] = base + a, 1.0 / sig
                    _accumulate(H, g, J, idx, 1, p[c, base + a] / sig, 1.0)
            for f in range(nf):
                x, y, th, dxt, dyt = _frame_pose(p, c, f, terms.odo, nf)
                base = 3 + nf + 3 * (f - 1)
                if priors.scale_weight > 0:
                    w = math.sqrt(priors.scale_weight) / priors.scale_sd
                    e = w * (p[c, 3 + f] - priors.scale_mu)
                    idx[0], J[0] = 3 + f, w
                    _accumulate(H, g, J, idx, 1, e, 1.0 / math.sqrt(1.0 + e * e))
                if priors.cam_weight > 0:
                    w = math.sqrt(priors.cam_weight) / priors.cam_sigma
                    ex = w * (x - priors.cam[c, f, 0])
                    ey = w * (y - priors.cam[c, f, 1])
                    tot = ex * ex + ey * ey
                    eh = 0.0
                    wh = 0.0
                    if priors.head_sigma > 0:
                        wh = math.sqrt(priors.cam_weight) / priors.head_sigma
                        eh = wh * _wrap(th - priors.head[c, f])
                        tot += eh * eh
                    rw = 1.0 / math.sqrt(1.0 + tot)
                    for axis in range(2):
                        e = ex if axis == 0 else ey
                        idx[0], J[0] = axis, w
                        idx[1], J[1] = 2, w * (dxt if axis == 0 else dyt)
                        nj = 2
                        if f > 0:
                            idx[2], J[2] = base + axis, w
                            nj = 3
                        _accumulate(H, g, J, idx, nj, e, rw)
                    if priors.head_sigma > 0:
                        idx[0], J[0] = 2, wh
                        nj = 1
                        if f > 0:
                            idx[1], J[1] = base + 2, wh
                            nj = 2
                        _accumulate(H, g, J, idx, nj, eh, rw)
            if priors.fix_sigma > 0:
                for axis in range(2):
                    e = (p[c, axis] - priors.fix[axis]) / priors.fix_sigma
                    idx[0], J[0] = axis, 1.0 / priors.fix_sigma
                    _accumulate(H, g, J, idx, 1, e, 1.0)
            if priors.fix_heading_sigma > 0:
                e = _wrap(p[c, 2] - priors.fix_heading) / priors.fix_heading_sigma
                idx[0], J[0] = 2, 1.0 / priors.fix_heading_sigma
                _accumulate(H, g, J, idx, 1, e, 1.0)
            if not damped_step(H, g, p, c, npar):
                break
    return p
