"""Geometric 3DoF solver: pose of a camera from a local object map and a reference object map.

No training. Given the query's local map (camera at the origin looking along +x, +y left), the
classes of its objects (known) and candidate reference objects (a region proposal or the whole
map, metric frame), find (x, y, theta) such that the query objects land on same-class reference
objects.

Two kinds of local map:

- ``metric=True`` (GT local maps, metres): a rigid copy of the reference; hypotheses are 2-point
  rigid fits of a same-class pair whose lengths agree, residuals are positions in metres.
- ``metric=False`` (depth local maps, unknown per-query scale): bearings are accurate (median
  error about 0.5 deg) while ranges are noisy (factor 0.6-2 after the best scale) and unscaled,
  so each hypothesis carries its own scale ``s`` (metres per local unit) and residuals are the
  bearing (weight 1/sigma_b) and the log-range (weight 1/sigma_r, much weaker).

Steps: (1) hypotheses from pairs of query objects x same-class ordered pairs of candidate
objects (2-point similarity: position, heading, scale), optionally kept only near a prior
(training-split cameras) and within a plausible scale; (2) MSAC scoring, vectorised: each query
object costs the smallest normalised squared residual over same-class candidates, truncated at
``tau**2``, plus prior costs (distance [and heading difference] to the nearest training camera,
log-scale for depth maps) when priors are given; (3) the ``top_k`` distinct hypotheses are refined
together (vectorised robust Gauss-Newton on their matches, with re-association), re-scored, and
the best wins. For depth maps hypotheses come from 3-bearing resections (range-free) and then
2-point similarities. The result holds
the pose, the inlier matches (query index, candidate index) and a confidence in [0, 1].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from . import geo


@dataclass
class SolverConfig:
    bearing_sigma_deg: float = 1.0      # depth maps: bearing noise
    log_range_sigma: float = 0.5        # depth maps: noise of log(range) after the scale (scoring)
    refine_log_range_sigma: float = 1.0  # depth maps: weaker range weight in the least squares
    position_sigma_m: float = 0.25      # GT maps: position noise (metres)
    tau: float = 3.0                    # residuals (in sigmas) beyond this are outliers
    max_pairs: int = 24                 # query pairs used to hypothesise (best conditioned first)
    max_triples: int = 30               # depth maps: query triples for 3-bearing resections
    max_triple_hyp: int = 20_000        # candidate triples per query triple at most (else skipped)
    max_hyp: int = 300_000              # hypotheses scored per query at most
    top_k: int = 12                     # hypotheses refined
    refine_rounds: int = 3              # re-association rounds in the refinement
    min_scale: float = 2.0              # depth maps: metres per local unit (median object range)
    max_scale: float = 150.0
    prior_radius_m: float = 15.0        # keep hypotheses within this of a prior camera (hard gate)
    prior_sigma_m: float = 3.0          # soft camera prior: cost (distance to nearest prior camera / sigma)^2
    prior_weight: float = 1.0           # 0 disables the soft camera prior (the hard gate stays)
    prior_heading_sigma_deg: float = 0.0  # >0 and prior headings given: joint (position, heading) prior
    prior_knn: int = 8                  # prior cameras considered per hypothesis for the joint prior
    scale_prior_weight: float = 1.0     # depth maps: weight of the log-scale prior (when one is given)
    covis_weight: float = 0.0           # >0 and prior_seen given: cost per matched object that no prior camera
                                        #   near the pose saw (co-visibility from the training split)
    covis_radius_m: float = 10.0        # prior cameras within this of the pose count for co-visibility
    covis_metric: bool = False          # apply co-visibility to metric (GT) maps too
    pair_len_tol_m: float = 0.5         # GT maps: same-class pairs must agree in length to this
    chunk: int = 8192
    early_stop: bool = True             # stop hypothesising once a hypothesis explains every object

    @classmethod
    def from_dict(cls, d: dict | None) -> "SolverConfig":
        d = dict(d or {})
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Solution:
    x: float
    y: float
    theta: float                        # radians, CCW from east
    scale: float                        # metres per local unit (1 for metric maps)
    inliers: list[tuple[int, int]] = field(default_factory=list)  # (query index, candidate index)
    confidence: float = 0.0
    cost: float = float("inf")          # MSAC cost of the returned pose
    n_hypotheses: int = 0


class _Problem:
    """Query, candidates and the same-class candidate lists as a padded (M, K) index matrix."""

    def __init__(self, q, q_cls, r, r_cls, metric: bool, cfg: SolverConfig, prior=None, scale_prior=None):
        self.prior = prior                  # cKDTree of plausible camera positions, or None
        self.prior_heading = None           # headings (rad) of the prior cameras, or None
        self.scale_prior = scale_prior      # (mean, std) of log(metres per local unit), or None
        self.seen = None                    # (P, N) bool: prior camera p saw candidate n (training split), or None
        self.q = np.asarray(q, float).reshape(-1, 2)
        self.qc = np.asarray(q_cls).astype(int).ravel()
        self.r = np.asarray(r, float).reshape(-1, 2)
        self.rc = np.asarray(r_cls).astype(int).ravel()
        self.metric = metric
        self.cfg = cfg
        self.m = len(self.q)
        self.q_bear = np.arctan2(self.q[:, 1], self.q[:, 0])
        self.q_range = np.linalg.norm(self.q, axis=1)
        self.same = [np.flatnonzero(self.rc == c) for c in self.qc]
        kmax = max([len(s) for s in self.same] + [1])
        self.cand = np.zeros((self.m, kmax), int)
        self.cmask = np.zeros((self.m, kmax), bool)
        for k, s in enumerate(self.same):
            self.cand[k, :len(s)] = s
            self.cmask[k, :len(s)] = True
        self.sb = np.radians(cfg.bearing_sigma_deg)
        # small-range guards (objects at the camera): log of (range + eps)
        self.eps_q = 0.02 * max(float(np.median(self.q_range)), 1e-9)
        cand_xy = self.r[self.cand] if len(self.r) else np.zeros(self.cand.shape + (2,))
        self.r_cand_x, self.r_cand_y = cand_xy[..., 0].copy(), cand_xy[..., 1].copy()  # (M, K)
        self.r_cand_x32, self.r_cand_y32 = self.r_cand_x.astype(np.float32), self.r_cand_y.astype(np.float32)
        self.q_range32 = (self.q_range + self.eps_q).astype(np.float32)  # range + guard

    # ------------------------------------------------------------------ costs
    def costs(self, t: np.ndarray, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(C, M, K) normalised squared residuals of every query object vs its same-class candidates."""
        if self.metric:
            rx = self.r_cand_x[None] - t[:, 0, None, None]  # (C, M, K) world offsets of the candidates
            ry = self.r_cand_y[None] - t[:, 1, None, None]
            c, sn = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
            lx = c * rx + sn * ry  # world -> camera frame
            ly = c * ry - sn * rx
            d2 = (lx - self.q[None, :, 0, None]) ** 2 + (ly - self.q[None, :, 1, None]) ** 2
            cost = d2 / self.cfg.position_sigma_m ** 2
        else:
            # float32 and a tangent for the bearing error: about 4x faster than float64 arctan2 on the
            # (C, M, K) arrays. tan(db) equals db to 0.1 % within the inlier cap (tau sigmas, a few
            # degrees); beyond it costs are capped anyway, and objects behind the camera get inf.
            f = np.float32
            rx = self.r_cand_x32[None] - t[:, 0, None, None].astype(f)
            ry = self.r_cand_y32[None] - t[:, 1, None, None].astype(f)
            wb = (theta[:, None] + self.q_bear[None]).astype(f)  # (C, M) query directions in the world
            ux, uy = np.cos(wb)[..., None], np.sin(wb)[..., None]
            along = ux * rx + uy * ry
            across = ux * ry - uy * rx
            with np.errstate(divide="ignore", invalid="ignore"):
                tan_db = np.where(along > 0, across / along, f(np.inf))
            rr = np.sqrt(rx * rx + ry * ry)
            sc = s.astype(f)[:, None, None]
            dr = np.log((rr + sc * f(self.eps_q)) / (sc * self.q_range32[None, :, None]))
            cost = (tan_db / f(self.sb)) ** 2 + (dr / f(self.cfg.log_range_sigma)) ** 2
        return np.where(self.cmask[None], cost, np.inf)

    def _pose_prior_sq(self, t, theta) -> np.ndarray:
        """(C,) squared normalised distance of poses to the prior cameras (position [+ heading])."""
        cfg = self.cfg
        if self.prior_heading is None or cfg.prior_heading_sigma_deg <= 0:
            d = self.prior.query(t, k=1)[0]
            return (d / cfg.prior_sigma_m) ** 2
        k = min(cfg.prior_knn, self.prior.n)
        d, j = self.prior.query(t, k=k)
        d, j = d.reshape(len(t), k), j.reshape(len(t), k)
        dth = geo.wrap_angle(self.prior_heading[j] - np.asarray(theta).reshape(-1, 1))
        return np.min((d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, axis=1)

    def prior_cost(self, t, s, theta=None) -> np.ndarray:
        """(C,) prior cost: pose vs the nearest prior camera, log-scale; each capped at tau^2."""
        tau2 = self.cfg.tau ** 2
        out = np.zeros(len(t))
        if self.prior is not None and self.cfg.prior_weight > 0:
            out += self.cfg.prior_weight * np.minimum(self._pose_prior_sq(t, theta), tau2)
        if not self.metric and self.scale_prior is not None and self.cfg.scale_prior_weight > 0:
            mu, sd = self.scale_prior
            out += self.cfg.scale_prior_weight * np.minimum(((np.log(s) - mu) / sd) ** 2, tau2)
        return out

    def covis_cost(self, t, inl, match) -> np.ndarray:
        """(C,) co-visibility cost: ``covis_weight`` per inlier whose candidate no prior camera within
        ``covis_radius_m`` of the pose saw together with the most of the others (best single camera)."""
        cfg = self.cfg
        if (self.seen is None or cfg.covis_weight <= 0 or self.prior is None
                or (self.metric and not cfg.covis_metric)):
            return np.zeros(len(t))
        k = min(cfg.prior_knn, self.prior.n)
        d, j = self.prior.query(t, k=k)
        d, j = d.reshape(len(t), k), j.reshape(len(t), k)
        seen = self.seen[j[..., None], match[:, None, :]] & inl[:, None, :]  # (C, k, M)
        cnt = np.where(d <= cfg.covis_radius_m, seen.sum(-1), 0).max(axis=1)
        return cfg.covis_weight * (inl.sum(1) - cnt)

    def score(self, t, theta, s):
        """MSAC cost (C,), inlier mask (C, M) and best candidate (C, M) per hypothesis."""
        cost = self.costs(t, theta, s)
        best = cost.argmin(axis=2)
        bc = np.take_along_axis(cost, best[..., None], axis=2)[..., 0]
        tau2 = self.cfg.tau ** 2
        inl = bc < tau2
        match = self.cand[np.arange(self.m)[None], best]
        total = np.minimum(bc, tau2).sum(axis=1) + self.prior_cost(t, s, theta) + self.covis_cost(t, inl, match)
        return total, inl, match

    # ------------------------------------------------------------------ hypotheses
    def pair_hypotheses(self, i: int, j: int):
        """2-point fits of query objects (i, j) onto every same-class ordered candidate pair (a, b)."""
        a, b = self.same[i], self.same[j]
        if not len(a) or not len(b):
            return None
        aa, bb = (g.ravel() for g in np.meshgrid(a, b, indexing="ij"))
        keep = aa != bb
        aa, bb = aa[keep], bb[keep]
        dq = self.q[j] - self.q[i]
        lq = float(np.hypot(*dq))
        if lq < 1e-9 or not len(aa):
            return None
        dr = self.r[bb] - self.r[aa]
        lr = np.hypot(dr[:, 0], dr[:, 1])
        if self.metric:
            ok = np.abs(lr - lq) <= self.cfg.pair_len_tol_m
            s = np.ones(len(aa))
        else:
            s = lr / lq
            ok = (s >= self.cfg.min_scale) & (s <= self.cfg.max_scale)
        aa, bb, dr, s = aa[ok], bb[ok], dr[ok], s[ok]
        theta = np.arctan2(dr[:, 1], dr[:, 0]) - np.arctan2(dq[1], dq[0])
        c, sn = np.cos(theta), np.sin(theta)
        qi = self.q[i]
        t = self.r[aa] - s[:, None] * np.column_stack([c * qi[0] - sn * qi[1], sn * qi[0] + c * qi[1]])
        return t, geo.wrap_angle(theta), s

    def triple_hypotheses(self, i: int, j: int, k: int, limit: int):
        """3-bearing resections (range-free) of query objects (i, j, k) onto same-class candidate triples.

        With u = 1 / (A - z) (complex, z the camera), the bearing condition
        arg((P - z) / (A - z)) = beta_P - beta_A reads Im(e^{-i alpha} ((P - A) u + 1)) = 0, linear
        in u; the two conditions for P = B, C fix u and so z; theta follows from A.
        """
        ca, cb, cc = self.same[i], self.same[j], self.same[k]
        if min(len(ca), len(cb), len(cc)) == 0 or len(ca) * len(cb) * len(cc) > limit:
            return None
        aa, bb, c3 = (g.ravel() for g in np.meshgrid(ca, cb, cc, indexing="ij"))
        keep = (aa != bb) & (bb != c3) & (aa != c3)
        aa, bb, c3 = aa[keep], bb[keep], c3[keep]
        if not len(aa):
            return None
        z_r = self.r[:, 0] + 1j * self.r[:, 1]
        A, B, C = z_r[aa], z_r[bb], z_r[c3]
        qb = self.q_bear
        eq = []
        for P, beta in ((B, qb[j]), (C, qb[k])):
            e = np.exp(-1j * (beta - qb[i]))
            kk = e * (P - A)  # Im(kk u) = -Im(e): Im(kk) ux + Re(kk) uy = -Im(e)
            eq.append((kk.imag, kk.real, -e.imag))
        (a11, a12, b1), (a21, a22, b2) = eq
        det = a11 * a22 - a12 * a21
        ok = np.abs(det) > 1e-12
        det = np.where(ok, det, 1.0)
        u = (b1 * a22 - a12 * b2) / det + 1j * (a11 * b2 - b1 * a21) / det
        ok &= np.abs(u) > 1e-12
        z = A - 1.0 / np.where(ok, u, 1.0)
        theta = np.angle(A - z) - qb[i]
        for P, beta in ((B, qb[j]), (C, qb[k])):  # each object ahead at its bearing, not behind
            ok &= np.abs(geo.wrap_angle(np.angle(P - z) - theta - beta)) < 1e-3
        d = np.abs(np.stack([A - z, B - z, C - z]))
        qr = self.q_range[[i, j, k]][:, None] + self.eps_q
        s = np.exp(np.mean(np.log(d + 1e-9) - np.log(qr), axis=0))
        if not self.metric:
            ok &= (s >= self.cfg.min_scale) & (s <= self.cfg.max_scale)
        else:
            s = np.ones_like(s)
        t = np.column_stack([z.real, z.imag])[ok]
        return t, geo.wrap_angle(theta[ok]), s[ok]

    def query_triples(self) -> list[tuple[int, int, int]]:
        m = self.m
        tr = [(i, j, k) for i in range(m) for j in range(i + 1, m) for k in range(j + 1, m)]
        key = []
        for i, j, k in tr:
            b = np.sort(self.q_bear[[i, j, k]])
            sep = min(b[1] - b[0], b[2] - b[1])  # the smaller gap conditions the resection
            n = len(self.same[i]) * len(self.same[j]) * len(self.same[k])
            key.append(-min(sep, np.radians(30.0)) / (1 + n) ** (1 / 3))
        order = np.argsort(key, kind="stable")
        return [tr[o] for o in order]

    def query_pairs(self) -> list[tuple[int, int]]:
        m = self.m
        pairs = [(i, j) for i in range(m) for j in range(i + 1, m)
                 if np.hypot(*(self.q[j] - self.q[i])) > 1e-9 and len(self.same[i]) and len(self.same[j])]
        if self.metric:  # longest pairs first (best conditioned); rarer classes first among ties
            key = [(-np.hypot(*(self.q[j] - self.q[i])) / (1 + 0.1 * len(self.same[i]) * len(self.same[j])))
                   for i, j in pairs]
        else:  # wide angular separation, similar ranges (ratio well determined), rare classes
            key = []
            for i, j in pairs:
                sep = abs(float(geo.wrap_angle(self.q_bear[i] - self.q_bear[j])))
                sep = min(sep, np.radians(60.0))
                key.append(-sep / np.sqrt(len(self.same[i]) * len(self.same[j])))
        order = np.argsort(key, kind="stable")
        return [pairs[k] for k in order]

    # ------------------------------------------------------------------ refinement
    def refine_batch(self, t: np.ndarray, theta: np.ndarray, s: np.ndarray, iters: int = 15):
        """Vectorised robust Gauss-Newton with re-association for C hypotheses at once.

        Objective: bearing + weak log-range residuals (positions for metric maps) of the matched
        inliers, plus the priors for depth maps; soft-L1 weights (IRLS), analytic Jacobians, a
        little Levenberg damping; matches re-associated ``refine_rounds`` times. Returns refined (t (C,2), theta (C,), s (C,)).
        """
        cfg = self.cfg
        C, m = len(t), self.m
        p = np.column_stack([t, theta, np.log(np.maximum(s, 1e-9))]).astype(float)
        tau2 = cfg.tau ** 2
        sb, sr, sp, eps = self.sb, cfg.refine_log_range_sigma, cfg.position_sigma_m, self.eps_q
        use_prior = self.prior is not None and cfg.prior_weight > 0 and not self.metric
        use_heading = use_prior and self.prior_heading is not None and cfg.prior_heading_sigma_deg > 0
        use_scale = not self.metric and self.scale_prior is not None and cfg.scale_prior_weight > 0
        npar = 3 if self.metric else 4
        for _ in range(cfg.refine_rounds):
            cost = self.costs(p[:, :2], p[:, 2], np.exp(p[:, 3]))  # (C, M, K)
            best = cost.argmin(axis=2)
            inl = np.take_along_axis(cost, best[..., None], axis=2)[..., 0] < tau2  # (C, M)
            R = self.r[self.cand[np.arange(m)[None], best]]  # (C, M, 2) matched candidates
            if use_prior:  # the prior camera each hypothesis is tied to, fixed for this round
                if use_heading:
                    k = min(cfg.prior_knn, self.prior.n)
                    d, j = self.prior.query(p[:, :2], k=k)
                    d, j = d.reshape(C, k), j.reshape(C, k)
                    dth = geo.wrap_angle(self.prior_heading[j] - p[:, 2:3])
                    sel = np.argmin((d / cfg.prior_sigma_m) ** 2 + (dth / np.radians(cfg.prior_heading_sigma_deg)) ** 2, 1)
                    jj = j[np.arange(C), sel]
                else:
                    jj = self.prior.query(p[:, :2], k=1)[1]
                cam = self.prior.data[jj]
            for _ in range(iters):
                rel = R - p[:, None, :2]
                c, sn = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
                if self.metric:
                    lx = c * rel[..., 0] + sn * rel[..., 1]
                    ly = -sn * rel[..., 0] + c * rel[..., 1]
                    e1, e2 = (lx - self.q[None, :, 0]) / sp, (ly - self.q[None, :, 1]) / sp
                    J1 = np.stack([-c.repeat(m, 1), -sn.repeat(m, 1), ly], -1) / sp
                    J2 = np.stack([sn.repeat(m, 1), -c.repeat(m, 1), -lx], -1) / sp
                else:
                    rho2 = np.maximum((rel ** 2).sum(-1), 1e-12)
                    rho = np.sqrt(rho2)
                    phi = np.arctan2(rel[..., 1], rel[..., 0])
                    e1 = geo.wrap_angle(phi - p[:, 2:3] - self.q_bear[None]) / sb
                    J1 = np.stack([rel[..., 1] / rho2, -rel[..., 0] / rho2, -np.ones_like(rho), np.zeros_like(rho)],
                                  -1) / sb
                    sc = np.exp(p[:, 3:4])
                    e2 = (np.log(rho + sc * eps) - np.log(sc * (self.q_range[None] + eps))) / sr
                    g = 1.0 / (rho + sc * eps)
                    J2 = np.stack([-rel[..., 0] / rho * g, -rel[..., 1] / rho * g, np.zeros_like(rho),
                                   sc * eps * g - 1.0], -1) / sr
                E = np.concatenate([e1, e2], 1)  # (C, 2M)
                J = np.concatenate([J1, J2], 1)[..., :npar]  # (C, 2M, P)
                W = np.concatenate([inl, inl], 1) / np.sqrt(1.0 + E ** 2)  # soft-L1 IRLS weights
                extra_e, extra_j = [], []
                if use_prior:
                    wpr = np.sqrt(cfg.prior_weight)
                    for a in range(2):
                        jrow = np.zeros((C, npar)); jrow[:, a] = wpr / cfg.prior_sigma_m
                        extra_e.append(wpr * (p[:, a] - cam[:, a]) / cfg.prior_sigma_m); extra_j.append(jrow)
                    if use_heading:
                        sh = np.radians(cfg.prior_heading_sigma_deg)
                        jrow = np.zeros((C, npar)); jrow[:, 2] = wpr / sh
                        extra_e.append(wpr * geo.wrap_angle(p[:, 2] - self.prior_heading[jj]) / sh); extra_j.append(jrow)
                if use_scale:
                    mu, sd = self.scale_prior
                    ws = np.sqrt(cfg.scale_prior_weight)
                    jrow = np.zeros((C, npar)); jrow[:, 3] = ws / sd
                    extra_e.append(ws * (p[:, 3] - mu) / sd); extra_j.append(jrow)
                if extra_e:
                    E = np.concatenate([E, np.stack(extra_e, 1)], 1)
                    J = np.concatenate([J, np.stack(extra_j, 1)], 1)
                    ex = np.stack(extra_e, 1)
                    # robust too (soft-L1 on the prior's total), so the data can overrule a far prior
                    W = np.concatenate([W, np.repeat(1.0 / np.sqrt(1.0 + (ex ** 2).sum(1, keepdims=True)),
                                                     len(extra_e), 1)], 1)
                JW = J * W[..., None]
                H = np.einsum("crp,crq->cpq", JW, J) + 1e-6 * np.eye(npar)[None]
                gvec = np.einsum("crp,cr->cp", JW, E)
                ok = inl.sum(1) >= 2
                try:
                    step = -np.linalg.solve(H, gvec[..., None])[..., 0]
                except np.linalg.LinAlgError:
                    step = np.zeros((C, npar))
                step = np.where(ok[:, None] & np.isfinite(step).all(1, keepdims=True), step, 0.0)
                p[:, :npar] += step
                if np.abs(step).max(initial=0.0) < 1e-10:
                    break
        return p[:, :2].copy(), geo.wrap_angle(p[:, 2]), np.exp(p[:, 3]) if not self.metric else np.ones(C)


def solve(query_xy, query_cls, ref_xy, ref_cls, metric: bool = False, config: SolverConfig | dict | None = None,
          prior_xy: np.ndarray | None = None, scale_prior: tuple[float, float] | None = None,
          prior_seen: np.ndarray | None = None) -> Solution | None:
    """Camera pose in the reference frame, or None when no hypothesis can be formed.

    ``query_xy``: (M, 2) local map; ``query_cls``: (M,) classes; ``ref_xy``/``ref_cls``: the
    candidate reference objects (metric frame); ``metric``: True for GT (metre) local maps,
    False for unscaled depth maps; ``prior_xy``: (P, 2) plausible camera positions (training
    cameras; a third column, their headings in radians, enables the joint pose prior when
    ``prior_heading_sigma_deg`` > 0) or None: hypotheses farther than ``prior_radius_m`` are dropped and the distance
    to the nearest one is a soft cost; ``scale_prior``: (mean, std) of log(metres per local
    unit) for depth maps (see :func:`fit_priors`); ``prior_seen``: (P, N) booleans, prior camera p
    saw reference row n (the matched objects of training queries), for the co-visibility cost
    (``covis_weight``). Inlier indices refer to rows of ``ref_xy``.
    """
    cfg = config if isinstance(config, SolverConfig) else SolverConfig.from_dict(config)
    prior_arr = np.asarray(prior_xy, float).reshape(len(prior_xy), -1) if prior_xy is not None else None
    prior = cKDTree(prior_arr[:, :2]) if prior_arr is not None and len(prior_arr) else None
    pb = _Problem(query_xy, query_cls, ref_xy, ref_cls, metric, cfg, prior, scale_prior)
    if prior is not None and prior_arr.shape[1] >= 3:
        pb.prior_heading = prior_arr[:, 2]
    if prior is not None and prior_seen is not None:
        pb.seen = np.asarray(prior_seen, bool).reshape(len(prior_arr), len(pb.r))
    if pb.m < 2 or len(pb.r) < 2:
        return None
    cand_cost, cand_t, cand_th, cand_s = [], [], [], []
    n_hyp = 0
    best_so_far = np.inf

    def batches():
        if not metric:  # range-free resections first: bearings are what depth maps get right
            for n, (i, j, k) in enumerate(pb.query_triples()):
                if n >= cfg.max_triples:
                    break
                yield pb.triple_hypotheses(i, j, k, cfg.max_triple_hyp)
        for n, (i, j) in enumerate(pb.query_pairs()):
            if n >= cfg.max_pairs:
                break
            yield pb.pair_hypotheses(i, j)

    pending: list[tuple] = []          # prior-gated batches waiting to be scored together

    def flush():
        """Score the pending batches in one pass (fewer, larger array operations) and keep each
        batch's top_k, as if scored one by one."""
        nonlocal best_so_far
        if not pending:
            return
        t = np.concatenate([b[0] for b in pending])
        th = np.concatenate([b[1] for b in pending])
        s = np.concatenate([b[2] for b in pending])
        cost = np.concatenate([pb.score(t[o:o + cfg.chunk], th[o:o + cfg.chunk], s[o:o + cfg.chunk])[0]
                               for o in range(0, len(t), cfg.chunk)])
        start = 0
        for bt, _, _ in pending:
            for o in range(0, len(bt), cfg.chunk):    # top_k per batch chunk, as before
                lo, hi = start + o, start + min(o + cfg.chunk, len(bt))
                top = lo + np.argsort(cost[lo:hi], kind="stable")[:cfg.top_k]
                cand_cost.append(cost[top]); cand_t.append(t[top]); cand_th.append(th[top]); cand_s.append(s[top])
                best_so_far = min(best_so_far, float(cost[top[0]]) if len(top) else np.inf)
            start += len(bt)
        pending.clear()

    n_pending = 0
    for n_batch, h in enumerate(batches()):
        if n_hyp >= cfg.max_hyp:
            break
        if h is None:
            continue
        t, th, s = h
        if prior is not None and len(t):
            near = prior.query(t, k=1, distance_upper_bound=cfg.prior_radius_m)[0] <= cfg.prior_radius_m
            t, th, s = t[near], th[near], s[near]
        if len(t):
            pending.append((t, th, s))
            n_pending += len(t)
        n_hyp += len(t)
        # GT maps: score every batch at once for the early stop (every object explained within a sigma)
        if metric or n_pending >= cfg.chunk:
            flush()
            n_pending = 0
        if cfg.early_stop and metric and best_so_far < pb.m and n_batch >= 1:
            break
    flush()
    if not cand_cost:
        return None
    cost = np.concatenate(cand_cost)
    t_all, th_all, s_all = np.concatenate(cand_t), np.concatenate(cand_th), np.concatenate(cand_s)
    order = np.argsort(cost, kind="stable")
    chosen: list[int] = []
    for w in order:  # the top_k distinct hypotheses (not within 1 m / 2 deg of a better one)
        if len(chosen) >= cfg.top_k:
            break
        if any(np.hypot(*(t_all[w] - t_all[v])) < 1.0 and abs(geo.wrap_angle(th_all[w] - th_all[v])) < np.radians(2)
               for v in chosen):
            continue
        chosen.append(int(w))
    ch = np.array(chosen, int)
    t_r, th_r, s_r = pb.refine_batch(t_all[ch], th_all[ch], s_all[ch])
    c_r, inl_r, match_r = pb.score(t_r, th_r, s_r)
    results = []
    for k in range(len(ch)):
        if not np.all(np.isfinite(t_r[k])) or (prior is not None and prior.query(t_r[k], k=1)[0] > 2 * cfg.prior_radius_m):
            continue
        results.append((float(c_r[k]), t_r[k], float(th_r[k]), float(s_r[k]), inl_r[k], match_r[k]))
    if not results:
        return None
    results.sort(key=lambda z: z[0])
    c, t, th, s, inl, match = results[0]
    inliers = [(int(k), int(match[k])) for k in range(pb.m) if inl[k]]
    # confidence: share of explained objects, lowered when a distinct pose is nearly as good
    conf = len(inliers) / pb.m
    for c2, t2, th2, *_ in results[1:]:
        if np.hypot(*(t2 - t)) > 2.0:
            conf *= float(1 - np.exp(-(c2 - c) / 2.0))
            break
    return Solution(float(t[0]), float(t[1]), float(th), float(s), inliers, float(conf), c, n_hyp)


def fit_priors(train_local_maps_m: list[np.ndarray]) -> tuple[float, float]:
    """Log-scale prior of depth maps from training GT (metre) local maps.

    Depth maps are normalised to a median object range of 1, so their scale in metres per unit
    is the median object range of the view: its log mean and std over training views.
    """
    med = np.array([np.median(np.linalg.norm(np.asarray(m, float), axis=1)) for m in train_local_maps_m])
    med = np.log(med[med > 0])
    return float(med.mean()), float(max(med.std(), 1e-3))
