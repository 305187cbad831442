"""The camera-prior gate answers like an exact nearest-camera query at any extent (a city's
cameras spread over kilometres used to fall back to one cell that rejected every point)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from flatlandia.fine import solver_priors
from flatlandia.fine.solver_priors import PriorGate


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


def test_a_camera_set_gets_its_grid_on_second_use_with_the_same_answers():
    rng = np.random.default_rng(3)
    cams = rng.uniform(0, 200, (50, 2))
    pts = rng.uniform(-20, 220, (2000, 2))
    solver_priors._GATES.clear()
    first = solver_priors.prior_gate(cams, 15.0)
    assert first.tree_only  # met once: no grid built
    second = solver_priors.prior_gate(cams, 15.0)
    assert not second.tree_only and solver_priors.prior_gate(cams, 15.0) is second  # built once, then cached
    np.testing.assert_array_equal(first.near(pts), second.near(pts))
