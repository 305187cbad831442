"""The camera-prior gate answers like an exact nearest-camera query at any extent (a city's
cameras spread over kilometres used to fall back to one cell that rejected every point)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from flatlandia.solver import priors
from flatlandia.solver.priors import PriorGate


@pytest.mark.parametrize("spread_m", [50.0, 5_000.0, 40_000.0])
def test_gate_equals_the_exact_query_at_any_extent(spread_m):
    rng = np.random.default_rng(0)
    sites = rng.uniform(0, spread_m, (4, 2))
    cams = np.vstack([s + rng.normal(0, 20, (30, 2)) for s in sites])
    pts = np.vstack([cams + rng.normal(0, 15, cams.shape), rng.uniform(-100, spread_m + 100, (500, 2))])
    gate = PriorGate(cams, 15.0)
    exact = cKDTree(cams).query(pts)[0] <= 15.0
    np.testing.assert_array_equal(gate.near(pts), exact)
    assert exact[: len(cams)].mean() > 0.4  # points near the cameras are kept, wherever they are
    if gate.cells <= PriorGate.MAX_CELLS:  # enough queries for the grid, where the extent allows one
        gate.near(np.zeros((int(PriorGate.GRID_AFTER * gate.cells) + 1, 2)))
    assert gate.tree_only == (spread_m > 1_000)
    np.testing.assert_array_equal(gate.near(pts), exact)  # the grid answers as the tree does


def test_the_grid_is_built_only_once_the_tree_has_answered_enough_points():
    """A camera set used for one query (the city search's) keeps the tree alone; a scene's, queried
    again and again, gets its grid once the points queried reach GRID_AFTER of its cells."""
    rng = np.random.default_rng(3)
    cams = rng.uniform(0, 200, (50, 2))
    pts = rng.uniform(-20, 220, (2000, 2))
    priors._GATES.clear()
    gate = priors.prior_gate(cams, 15.0)
    first = gate.near(pts)
    assert gate.tree_only and priors.prior_gate(cams, 15.0) is gate  # cached
    needed = int(np.ceil(PriorGate.GRID_AFTER * gate.cells))
    while gate.queried + len(pts) < needed:
        gate.near(pts)
    assert gate.tree_only
    np.testing.assert_array_equal(gate.near(pts), first)
    assert not gate.tree_only  # built now, same answers
    np.testing.assert_array_equal(gate.near(pts), first)
