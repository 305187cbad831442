"""Compiled (numba) loop of the city index: how well a query lines up with each candidate view.

Why compiled: every query checks a few hundred views, each by trying every same-class (query
object, seen object) pair as the alignment; in Python that costs more than the
solver's whole search (docs/measurements.md, "City search").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: added to a view's object ranges before the log (an object at the camera)
RANGE_FLOOR_M = 0.5


@njit(cache=True, inline="always")
def _wrap(a):
    if a > math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


@njit(cache=True)
def view_agreement(views, ptr, seen_cls, seen_bear, seen_logr, q_cls, q_bear, q_logr, q_w, tol_b, tol_r):
    """(V,) per view of ``views``: the largest weight of query objects that one heading offset and
    one log scale align with same-class objects the view saw (bearing within ``tol_b`` radians,
    log range within ``tol_r``). Each (query object, seen object) pair of one class proposes the
    offset and the scale; a query object counts once. ``q_logr`` is the log of the query's
    (unscaled) ranges, so the scale is a free offset of the log ranges."""
    m = q_cls.shape[0]
    out = np.zeros(views.shape[0])
    for i in range(views.shape[0]):
        a, b = ptr[views[i]], ptr[views[i] + 1]
        best = 0.0
        for k0 in range(m):
            for j0 in range(a, b):
                if seen_cls[j0] != q_cls[k0]:
                    continue
                d0 = _wrap(seen_bear[j0] - q_bear[k0])
                l0 = seen_logr[j0] - q_logr[k0]
                s = 0.0
                for k in range(m):
                    for j in range(a, b):
                        if seen_cls[j] != q_cls[k]:
                            continue
                        if (
                            abs(_wrap(seen_bear[j] - q_bear[k] - d0)) < tol_b
                            and abs(seen_logr[j] - q_logr[k] - l0) < tol_r
                        ):
                            s += q_w[k]
                            break
                if s > best:
                    best = s
        out[i] = best
    return out
