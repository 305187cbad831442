"""Answers of several regions of one map, solved one by one, as one answer.

Why: a city's index proposes a handful of places; solved as one union, the pool the probability is
normalised over is whatever the union's cost liked best, so a place whose region held few objects
hardly appears in it. Solved one by one, each region gets a complete pool of its own (seeded at
its own views: :mod:`flatlandia.solver.camera_hypotheses`), and the regions' evidence adds up: an answer's
share is its place's evidence over the evidence of every distinct place any region found, plus
what the regions' pools held beyond those places, plus the null hypothesis' for a single frame
(:func:`combine`). Two identical places in two regions then split the evidence, as two identical
places of one map do.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from flatlandia.solver import calibration


def _same_place(a, b) -> bool:
    turn = abs((a.theta - b.theta + math.pi) % (2 * math.pi) - math.pi)
    return math.hypot(a.x - b.x, a.y - b.y) < calibration.RIGHT_M and turn < math.radians(calibration.RIGHT_DEG)


def combine(found: list, cal, objects: int, frames: int = 1, alternatives: int = 0):
    """(best, alternatives) over the regions' answers ``found`` (one ``Localization`` or
    ``SequenceLocalization`` per region): the distinct places of every region (a place two regions
    found counts once, at its larger evidence) ranked by evidence; each answer's ``share`` is its
    place's evidence over the total (:func:`calibration.null_share`; the null hypothesis of ``cal``
    for a single frame) and its ``probability`` the calibration of that share (``objects`` seen by
    the anchor, ``frames``, the answer's own agreement), and the index of the region whose place
    won. (None, [], -1) when no region found a pose."""
    places, rests = [], []
    for r, loc in enumerate(found):
        sols = [s for s in [loc.best, *loc.alternatives] if s is not None and s.log_place is not None]
        sols = [s for s in sols if math.isfinite(s.log_place)]
        if not sols:
            continue
        own = np.logaddexp.reduce([s.log_place for s in sols])
        pool = float(sols[0].log_pool)
        if pool > own + 1e-12:  # what this region's pool held beyond the places it returned
            rests.append(pool + math.log(-math.expm1(own - pool)))
        places.extend((s, r) for s in sols)
    if not places:
        return None, [], -1
    places.sort(key=lambda sr: -sr[0].log_place)
    distinct, winner = [], places[0][1]
    for s, _ in places:
        if not any(_same_place(s, d) for d in distinct):
            distinct.append(s)
    total = float(np.logaddexp.reduce([d.log_place for d in distinct] + rests))
    null_key = cal.null_key if cal is not None and frames <= 1 else None
    shares = calibration.null_share(np.array([d.log_place for d in distinct]), total, null_key)
    agreement = np.array([1.0 if d.agreement is None else d.agreement for d in distinct])
    prob = calibration.probability(cal, shares, objects, frames, agreement)
    key0 = distinct[0].log_place
    out = [
        dataclasses.replace(
            d,
            share=float(sh),
            probability=float(p),
            behind=float(key0 - d.log_place),
            log_pool=total,
        )
        for d, sh, p in zip(distinct, shares, prob)
    ]
    return out[0], out[1 : 1 + alternatives], winner
