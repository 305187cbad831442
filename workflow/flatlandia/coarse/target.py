"""Neighbourhood similarity ``S_{i->Q} = (1 - d_p) (1 - d_s)``: the regression target of the Sim loss.

For a query ``Q`` (its GT local map, metres, camera frame) and a reference node ``i``:

* **neighbourhood** ``N_i``: ``i`` and the reference objects within ``radius_m`` (default 30 m)
  of it, at most ``max_neighbours`` (default 24) nearest ones;
* **subsets and their alignment**: a subset of ``N_i`` is aligned to ``Q`` by a rigid 2D motion
  (GT local maps are metric, so no scale). Each query object ``j`` is matched to the nearest
  object of its class in ``N_i`` after the motion, at residual ``r_j``; the matched objects with
  ``r_j < cap_m`` form the subset. Objects without a match inside ``cap_m`` count as ``cap_m``;
* ``d_p`` = ``mean_j min(r_j, cap_m) / cap_m`` in [0, 1] (0: every query object lands on an
  object of its class; 1: no alignment of two or more objects exists in ``N_i``), minimised
  over motions;
* ``d_s`` = mean distance of the subset of the best motion to ``i``, divided by ``radius_m``
  (every member lies within ``radius_m`` of ``i``, so ``d_s`` is in [0, 1]).

Where this is exact and where it approximates:

* **Motions are enumerated exhaustively** (no sampling): every correspondence of an unordered
  query pair ``(a, b)`` with an ordered pair ``(u, v)`` of ``N_i`` with the same classes and
  lengths within ``pair_tol_m`` defines one motion (the midpoints coincide, the directions
  agree). The best pair motion of each node is then refined by one least-squares (Procrustes)
  refit on its matched objects, and the smaller residual is kept. Any subset aligned with
  residual 0 (as the true matched objects are, to 1e-8 m, for GT maps) contains such a pair,
  so the minimum ``d_p = 0`` is found exactly; for imperfect alignments the residual is that
  of the best pair-generated motion after one refit, an upper bound on the true optimum.
* The matching is nearest-of-class, not one-to-one: two query objects may share a reference
  object (only possible when two same-class query objects are closer than ``2 cap_m`` after
  alignment); enforcing injectivity would need an assignment per hypothesis.
* The target is computed from the **GT local map** for both map types: it describes where the
  query truly is; depth maps are the noisy input the model must map to the same target.

Cost: hypotheses are built per scene as (node, ordered pair in its neighbourhood) triples once,
then matched to each query's pairs by class key and length; all residuals are evaluated as
one (hypotheses x query objects x neighbourhood) array per chunk.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import config
from flatlandia.data import localmaps


@config.settings("coarse.similarity", frozen=True)
class SimilarityConfig:
    """Settings of the Sim loss's target: the config section ``coarse.similarity`` (each is described
    in config/README.md, ``coarse.similarity.*``)."""


#: the settings at the schema's defaults (the functions' default argument)
DEFAULT_SIMILARITY = SimilarityConfig()


class SceneIndex:
    """Per-scene precomputation: neighbourhoods and every (node, ordered pair) hypothesis anchor."""

    def __init__(self, ref_xy: np.ndarray, ref_cls, cfg: SimilarityConfig = DEFAULT_SIMILARITY, n_classes: int = 64):
        self.xy = np.asarray(ref_xy, float).reshape(-1, 2)
        self.cls = np.asarray(ref_cls, int)
        self.cfg = cfg
        self.n_classes = n_classes
        n = len(self.xy)
        d = np.linalg.norm(self.xy[:, None] - self.xy[None], axis=-1)
        k = min(cfg.max_neighbours, n)
        order = np.argsort(d, axis=1, kind="stable")[:, :k]  # node itself first (distance 0)
        # make sure the node is in its own neighbourhood even with exact duplicates
        self_pos = order == np.arange(n)[:, None]
        missing = ~self_pos.any(1)
        order[missing, 0] = np.flatnonzero(missing)
        self.nbr = order  # (n, k)
        self.valid = np.take_along_axis(d, order, 1) <= cfg.radius_m + 1e-9
        self.valid[np.arange(n), 0] |= True
        # anchors: (node i, slot p, slot q) with p != q both valid
        kk = np.arange(k)
        P, Q = np.meshgrid(kk, kk, indexing="ij")
        off = P != Q
        P, Q = P[off], Q[off]
        I = np.repeat(np.arange(n), len(P))
        P = np.tile(P, n)
        Q = np.tile(Q, n)
        ok = self.valid[I, P] & self.valid[I, Q]
        I, P, Q = I[ok], P[ok], Q[ok]
        U, V = self.nbr[I, P], self.nbr[I, Q]
        key = self.cls[U] * n_classes + self.cls[V]
        srt = np.argsort(key, kind="stable")
        self.a_node, self.a_u, self.a_v = I[srt], U[srt], V[srt]
        self.a_len = np.linalg.norm(self.xy[self.a_v] - self.xy[self.a_u], axis=1)
        self.a_key = key[srt]

    def anchors_for(self, key: int) -> slice:
        lo, hi = np.searchsorted(self.a_key, [key, key + 1])
        return slice(int(lo), int(hi))


def _rot(c, s, pts):
    """Rotate (..., M, 2) points by angles given as cos/sin of shape (...)."""
    x, y = pts[..., 0], pts[..., 1]
    return np.stack([c[..., None] * x - s[..., None] * y, s[..., None] * x + c[..., None] * y], axis=-1)


def _class_mask(index: SceneIndex, q_cls: np.ndarray) -> np.ndarray:
    """(n, M, K): may query object j match neighbourhood slot k of node i (same class, in radius)."""
    return (index.cls[index.nbr][:, None, :] == q_cls[None, :, None]) & index.valid[:, None, :]


def _residuals(index: SceneIndex, nodes, c, s, t, q_xy, mask, want_match: bool = True):
    """Per hypothesis: (H, M) capped residuals and matched reference rows (-1: none); vectorised."""
    cfg = index.cfg
    px = c[:, None] * q_xy[None, :, 0] - s[:, None] * q_xy[None, :, 1] + t[:, None, 0]  # (H, M)
    py = s[:, None] * q_xy[None, :, 0] + c[:, None] * q_xy[None, :, 1] + t[:, None, 1]
    nb = index.nbr[nodes]  # (H, K)
    d2 = (px[:, :, None] - index.xy[nb, 0][:, None, :]) ** 2 + (py[:, :, None] - index.xy[nb, 1][:, None, :]) ** 2
    d2 = np.where(mask[nodes], d2, np.inf)
    if not want_match:
        return np.minimum(np.sqrt(d2.min(-1)), cfg.cap_m), None
    best = d2.argmin(-1)  # (H, M)
    r = np.sqrt(np.take_along_axis(d2, best[..., None], -1)[..., 0])
    matched = np.where(r < cfg.cap_m, np.take_along_axis(nb, best, 1), -1)
    return np.minimum(r, cfg.cap_m), matched


def _procrustes(src: np.ndarray, dst: np.ndarray, w: np.ndarray):
    """Weighted rigid fit per hypothesis: src, dst (H, M, 2), weights (H, M) -> cos, sin, t."""
    ws = w.sum(1, keepdims=True)
    ws = np.where(ws > 0, ws, 1.0)
    ms = (w[..., None] * src).sum(1) / ws
    md = (w[..., None] * dst).sum(1) / ws
    a, b = src - ms[:, None], dst - md[:, None]
    sxx = (w * (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1])).sum(1)
    sxy = (w * (a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])).sum(1)
    ang = np.arctan2(sxy, sxx)
    c, s = np.cos(ang), np.sin(ang)
    t = md - _rot(c, s, ms[:, None, :])[:, 0]
    return c, s, t


def node_similarity(index: SceneIndex, q_xy: np.ndarray, q_cls) -> pd.DataFrame:
    """``S, d_p, d_s, n_matched`` of every reference node (rows in index order) for one query."""
    cfg = index.cfg
    q_xy = np.asarray(q_xy, float).reshape(-1, 2)
    q_cls = np.asarray(q_cls, int)
    m, n = len(q_xy), len(index.xy)
    # hypotheses: unordered query pairs x anchors with the same ordered classes and similar length
    hyp_node, hyp_a, hyp_b, hyp_u, hyp_v = [], [], [], [], []
    for a in range(m):
        for b in range(a + 1, m):
            sl = index.anchors_for(int(q_cls[a]) * index.n_classes + int(q_cls[b]))
            if sl.stop == sl.start:
                continue
            lq = np.linalg.norm(q_xy[b] - q_xy[a])
            sel = np.flatnonzero(np.abs(index.a_len[sl] - lq) <= cfg.pair_tol_m) + sl.start
            if sel.size:
                hyp_node.append(index.a_node[sel])
                hyp_u.append(index.a_u[sel])
                hyp_v.append(index.a_v[sel])
                hyp_a.append(np.full(sel.size, a))
                hyp_b.append(np.full(sel.size, b))
    dp = np.ones(n)
    ds = np.zeros(n)
    nmatch = np.zeros(n, int)
    if hyp_node:
        node = np.concatenate(hyp_node)
        A, B, U, V = (np.concatenate(x) for x in (hyp_a, hyp_b, hyp_u, hyp_v))
        # motion: query pair direction onto reference pair direction, midpoints coincide
        dq = q_xy[B] - q_xy[A]
        dr = index.xy[V] - index.xy[U]
        ang = np.arctan2(dr[:, 1], dr[:, 0]) - np.arctan2(dq[:, 1], dq[:, 0])
        c, s = np.cos(ang), np.sin(ang)
        mq = (q_xy[A] + q_xy[B]) / 2
        t = (index.xy[U] + index.xy[V]) / 2 - _rot(c, s, mq[:, None, :])[:, 0]
        mask = _class_mask(index, q_cls)
        best_e = np.full(n, np.inf)
        best_h = np.full(n, -1)
        for lo in range(0, len(node), cfg.chunk):
            sl = slice(lo, lo + cfg.chunk)
            r, _ = _residuals(index, node[sl], c[sl], s[sl], t[sl], q_xy, mask, want_match=False)
            e = r.mean(1) / cfg.cap_m
            # best hypothesis per node within the chunk (lexsort: node, then residual)
            o = np.lexsort((e, node[sl]))
            first = np.r_[True, node[sl][o][1:] != node[sl][o][:-1]]
            nodes_c, e_c, h_c = node[sl][o][first], e[o][first], o[first] + lo
            better = e_c < best_e[nodes_c]
            best_e[nodes_c[better]] = e_c[better]
            best_h[nodes_c[better]] = h_c[better]
        has = np.flatnonzero(best_h >= 0)
        h = best_h[has]
        r0, m0 = _residuals(index, has, c[h], s[h], t[h], q_xy, mask)
        # one Procrustes refit on the matched objects of the best pair motion
        w = (m0 >= 0).astype(float)
        dst = index.xy[np.where(m0 >= 0, m0, 0)]
        c1, s1, t1 = _procrustes(np.broadcast_to(q_xy, (len(has), m, 2)), dst, w)
        r1, m1 = _residuals(index, has, c1, s1, t1, q_xy, mask)
        e0, e1 = r0.mean(1) / cfg.cap_m, r1.mean(1) / cfg.cap_m
        use1 = (e1 < e0) & (w.sum(1) >= 2)
        e = np.where(use1, e1, e0)
        mt = np.where(use1[:, None], m1, m0)
        dp[has] = np.clip(e, 0.0, 1.0)
        # d_s: mean distance to the node of the matched subset (each reference object once)
        srt = np.sort(mt, axis=1)  # -1 (unmatched) first
        uniq = (srt >= 0) & np.c_[np.ones(len(has), bool), srt[:, 1:] != srt[:, :-1]]
        dist = np.linalg.norm(index.xy[np.maximum(srt, 0)] - index.xy[has][:, None], axis=-1)
        nmatch[has] = uniq.sum(1)
        mean_d = (dist * uniq).sum(1) / np.maximum(nmatch[has], 1)
        ds[has] = np.clip(np.where(nmatch[has] > 0, mean_d, cfg.radius_m) / cfg.radius_m, 0.0, 1.0)
    ds[dp >= 1.0] = 1.0
    S = (1.0 - dp) * (1.0 - ds)
    return pd.DataFrame({"S": S, "d_p": dp, "d_s": ds, "n_matched": nmatch})


def scene_similarity(
    ref: pd.DataFrame, queries: pd.DataFrame, cfg: SimilarityConfig = DEFAULT_SIMILARITY, progress=None
) -> pd.DataFrame:
    """The similarity table of a scene: one row per (query, reference object), GT local maps.

    Columns ``scene, token, obj_idx, S, d_p, d_s, n_matched`` (float32 for the scores).
    """
    index = SceneIndex(ref[["x_m", "y_m"]].to_numpy(float), ref["class_id"].to_numpy(), cfg)
    obj = ref["obj_idx"].to_numpy(np.int64)
    parts = []
    rows = list(queries.itertuples(index=False))
    for r in progress(rows) if progress else rows:
        df = node_similarity(index, localmaps.xy(r.gt_local_xy_m), np.asarray(r.classes, int))
        df.insert(0, "obj_idx", obj)
        df.insert(0, "token", str(r.token))
        df.insert(0, "scene", str(r.scene))
        parts.append(df)
    cols = ["scene", "token", "obj_idx", "S", "d_p", "d_s", "n_matched"]
    if not parts:
        return pd.DataFrame(columns=cols)
    out = pd.concat(parts, ignore_index=True)
    for c in ("S", "d_p", "d_s"):
        out[c] = out[c].astype(np.float32)
    out["n_matched"] = out["n_matched"].astype(np.int16)
    return out[cols]
