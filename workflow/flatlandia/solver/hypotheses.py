"""Pose hypotheses of the solver: where they come from, and which ones are kept.

Depth maps first get 3-bearing resections (range-free: bearings are what depth maps get right),
then 2-point fits of query pairs onto same-class candidate pairs (position, heading and, for
depth maps, scale). Hypotheses are gated by the prior cameras, scored in large chunks, and each
batch keeps its ``top_k``; :func:`distinct_best` picks the ``top_k`` distinct ones to refine.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from flatlandia import geo
from flatlandia.solver import kernels, scoring
from flatlandia.solver.kernels import CoSeen
from flatlandia.solver.priors import Priors
from flatlandia.solver.problem import Problem


def query_pairs(problem: Problem) -> list[tuple[int, int]]:
    """Query object pairs with candidates, best conditioned first."""
    q, same = problem.q, problem.same
    m = problem.m
    pairs = [
        (i, j)
        for i in range(m)
        for j in range(i + 1, m)
        if np.hypot(*(q[j] - q[i])) > 1e-9 and len(same[i]) and len(same[j])
    ]
    if problem.metric:  # longest pairs first; rarer classes first among ties
        key = [(-np.hypot(*(q[j] - q[i])) / (1 + 0.1 * len(same[i]) * len(same[j]))) for i, j in pairs]
    else:  # wide angular separation, rare classes
        key = []
        for i, j in pairs:
            sep = abs(float(geo.wrap_angle(problem.q_bear[i] - problem.q_bear[j])))
            sep = min(sep, np.radians(60.0))
            key.append(-sep / np.sqrt(len(same[i]) * len(same[j])))
    order = np.argsort(key, kind="stable")
    return [pairs[k] for k in order]


def query_triples(problem: Problem) -> list[tuple[int, int, int]]:
    """Query object triples, widest bearing gaps and fewest candidate triples first."""
    m = problem.m
    triples = [(i, j, k) for i in range(m) for j in range(i + 1, m) for k in range(j + 1, m)]
    key = []
    for i, j, k in triples:
        b = np.sort(problem.q_bear[[i, j, k]])
        sep = min(b[1] - b[0], b[2] - b[1])  # the smaller gap conditions the resection
        n = len(problem.same[i]) * len(problem.same[j]) * len(problem.same[k])
        key.append(-min(sep, np.radians(30.0)) / (1 + n) ** (1 / 3))
    order = np.argsort(key, kind="stable")
    return [triples[o] for o in order]


#: the kernels' placeholder when the gate is off
_NO_COSEEN = CoSeen(np.zeros((1, 1), np.bool_), np.zeros(2, np.int64), np.zeros(0, np.int64))


def _coseen(problem: Problem, priors: Priors):
    """The co-visibility gate of the kernels, (lists, on): on for regions of more than
    ``covis_gate_above`` candidates when the priors know what the training cameras saw together."""
    if priors.coseen is None or len(problem.r) <= problem.cfg.covis_gate_above:
        return _NO_COSEEN, False
    return priors.coseen, True


def pair_hypotheses(problem: Problem, priors: Priors, i: int, j: int):
    """2-point fits of query objects (i, j) onto every same-class ordered candidate pair (a, b)."""
    a, b = problem.same[i], problem.same[j]
    if not len(a) or not len(b):
        return None
    dq = problem.q[j] - problem.q[i]
    if float(np.hypot(*dq)) < 1e-9:
        return None
    cfg = problem.cfg
    return kernels.pair_fits(
        a.astype(np.int64),
        b.astype(np.int64),
        *_coseen(problem, priors),
        problem.rx,
        problem.ry,
        float(problem.q[i, 0]),
        float(problem.q[i, 1]),
        float(dq[0]),
        float(dq[1]),
        problem.metric,
        float(cfg.pair_len_tol_m),
        float(cfg.min_scale),
        float(cfg.max_scale),
    )


def triple_hypotheses(problem: Problem, priors: Priors, i: int, j: int, k: int, limit: int):
    """3-bearing resections (range-free) of query objects (i, j, k) onto same-class candidate triples.

    With u = 1 / (A - z) (complex, z the camera), the bearing condition
    arg((P - z) / (A - z)) = beta_P - beta_A reads Im(e^{-i alpha} ((P - A) u + 1)) = 0, linear
    in u; the two conditions for P = B, C fix u and so z; theta follows from A.
    """
    ca, cb, cc = problem.same[i], problem.same[j], problem.same[k]
    co, use_co = _coseen(problem, priors)
    if min(len(ca), len(cb), len(cc)) == 0 or (not use_co and len(ca) * len(cb) * len(cc) > limit):
        return None
    qb, qr, cfg = problem.q_bear, problem.q_range, problem.cfg
    return kernels.triple_resections(
        ca.astype(np.int64),
        cb.astype(np.int64),
        cc.astype(np.int64),
        co,
        use_co,
        problem.rx,
        problem.ry,
        float(qb[i]),
        float(qb[j]),
        float(qb[k]),
        float(qr[i]),
        float(qr[j]),
        float(qr[k]),
        float(problem.eps_q),
        float(cfg.min_scale),
        float(cfg.max_scale),
        problem.metric,
    )


def hypothesis_batches(problem: Problem, priors: Priors) -> Iterator:
    """(t, theta, s) batches, or None where a query tuple has no candidates: resections of the
    first ``max_triples`` triples (depth maps), then fits of the first ``max_pairs`` pairs."""
    cfg = problem.cfg
    if not problem.metric:
        for i, j, k in query_triples(problem)[: cfg.max_triples]:
            yield triple_hypotheses(problem, priors, i, j, k, cfg.max_triple_hyp)
    for i, j in query_pairs(problem)[: cfg.max_pairs]:
        yield pair_hypotheses(problem, priors, i, j)


class ScoredHypotheses:
    """Hypotheses scored in chunks of ``chunk`` (fewer, larger array operations); of each batch
    chunk only the ``keep`` cheapest are kept, as if every batch were scored on its own."""

    def __init__(self, problem: Problem, priors: Priors, keep: int):
        self.problem, self.priors, self.keep = problem, priors, keep
        self.pending: list[tuple] = []  # gated batches waiting to be scored together
        self.n_pending = 0
        self.kept: list[tuple] = []  # (cost, t, theta, s) of the kept hypotheses, per chunk
        self.best = np.inf  # lowest cost so far
        self.n_hypotheses = 0

    def add(self, t, theta, s) -> None:
        """Queue a batch; it is gated by the prior cameras and scored at the next :meth:`flush`."""
        if len(t):
            self.pending.append((t, theta, s))
            self.n_pending += len(t)

    def flush(self) -> None:
        """Gate the pending batches together, score them in one pass and keep each batch chunk's
        ``keep`` cheapest."""
        self.n_pending = 0
        if not self.pending:
            return
        chunk, top_k = self.problem.cfg.chunk, self.keep
        sizes = [len(b[0]) for b in self.pending]
        t, th, s = (np.concatenate([b[n] for b in self.pending]) for n in range(3))
        self.pending.clear()
        near = self.priors.near(t)
        batch = np.repeat(np.arange(len(sizes)), sizes)[near]
        t, th, s = t[near], th[near], s[near]
        self.n_hypotheses += len(t)
        if not len(t):
            return
        cost = self._chunked_cost(t, th, s)
        start = 0
        for size in np.bincount(batch, minlength=len(sizes)).tolist():
            for o in range(0, size, chunk):
                lo, hi = start + o, start + min(o + chunk, size)
                top = lo + np.argsort(cost[lo:hi], kind="stable")[:top_k]
                self.kept.append((cost[top], t[top], th[top], s[top]))
                self.best = min(self.best, float(cost[top[0]]) if len(top) else np.inf)
            start += size

    def _chunked_cost(self, t, theta, s) -> np.ndarray:
        """(C,) MSAC cost, scored ``chunk`` hypotheses at a time (bounded temporaries)."""
        chunk = self.problem.cfg.chunk
        costs = []
        for o in range(0, len(t), chunk):
            window = slice(o, o + chunk)
            costs.append(scoring.score(self.problem, self.priors, t[window], theta[window], s[window])[0])
        return np.concatenate(costs)

    def arrays(self, keep: int | None = None):
        """(cost, t, theta, s) of every kept hypothesis, or None when none was kept; with ``keep``
        (at most the scoring's), each chunk's ``keep`` cheapest only: what scoring with that
        ``keep`` would have kept (a chunk's kept are sorted by cost)."""
        if not self.kept:
            return None
        n = self.keep if keep is None else int(keep)
        return tuple(np.concatenate([k[i][:n] for k in self.kept]) for i in range(4))


def score_hypotheses(problem: Problem, priors: Priors, keep: int) -> ScoredHypotheses:
    """Generate, gate and score hypotheses until ``max_hyp``, keeping the ``keep`` cheapest of each
    batch chunk; GT maps score every batch at once and stop early once a hypothesis explains every
    object within a sigma (``early_stop``)."""
    cfg = problem.cfg
    scored = ScoredHypotheses(problem, priors, keep)
    for n_batch, batch in enumerate(hypothesis_batches(problem, priors)):
        if scored.n_hypotheses >= cfg.max_hyp:
            break
        if batch is None:
            continue
        scored.add(*batch)
        if problem.metric or scored.n_pending >= cfg.chunk:
            scored.flush()
        if cfg.early_stop and problem.metric and scored.best < problem.m and n_batch >= 1:
            break
    scored.flush()
    return scored


def distinct_best(cost, t, theta, top_k: int) -> np.ndarray:
    """Indices of the ``top_k`` cheapest hypotheses, skipping any within 1 m and 2 degrees of a
    cheaper one already chosen (compiled: a seeded pool holds hundreds)."""
    order = np.argsort(cost, kind="stable").astype(np.int64)
    t = np.ascontiguousarray(t, dtype=float).reshape(-1, 2)
    theta = np.ascontiguousarray(theta, dtype=float).ravel()
    return kernels.distinct_in_order(order, t[:, 0].copy(), t[:, 1].copy(), theta, int(top_k), 1.0, math.radians(2.0))
