"""The bearing solver: exact on noise-free maps, graceful with noise, real GT maps solved to 0 m."""

import numpy as np
import pytest

from flatlandia import bearing_solver as bs
from flatlandia import geo


def _scene(seed=0, n_ref=60, n_q=6):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(-60, 60, size=(n_ref, 2))
    cls = rng.integers(0, 20, n_ref)  # a typical map holds 10-30 classes
    cam, theta = np.array([3.0, -2.0]), 0.7
    local_all = geo.world_to_local(ref, cam, theta)
    ahead = np.flatnonzero((local_all[:, 0] > 5) & (np.abs(local_all[:, 1]) < local_all[:, 0]))
    pick = rng.choice(ahead, n_q, replace=False)
    return ref, cls, cam, theta, local_all[pick], cls[pick], pick


def test_exact_on_noise_free_maps_and_any_scale():
    ref, cls, cam, theta, local, qcls, pick = _scene()
    for scale in (1.0, 0.013):  # GT map (metres) and an unscaled depth-like map
        p = bs.solve(local * scale, qcls, ref, cls)
        assert np.hypot(p.x - cam[0], p.y - cam[1]) < 1e-6
        assert abs(geo.wrap_angle(p.theta - theta)) < 1e-8
        assert sorted(r for _, r in p.inliers) == sorted(pick) and p.confidence == 1.0


def test_graceful_with_range_noise_and_an_outlier():
    ref, cls, cam, theta, local, qcls, _ = _scene(seed=3, n_q=7)
    rng = np.random.default_rng(1)
    bearing = np.arctan2(local[:, 1], local[:, 0]) + np.radians(rng.normal(0, 0.5, len(local)))
    rng_noisy = np.linalg.norm(local, axis=1) * rng.uniform(0.7, 1.3, len(local))
    noisy = np.column_stack([np.cos(bearing), np.sin(bearing)]) * rng_noisy[:, None] * 0.01
    noisy[0] = [0.3, -0.2]  # an outlier detection
    p = bs.solve(noisy, qcls, ref, cls)
    assert np.hypot(p.x - cam[0], p.y - cam[1]) < 2.0
    assert abs(np.degrees(geo.wrap_angle(p.theta - theta))) < 2.0
    assert p.confidence >= 5 / 7


def test_nothing_to_solve():
    assert bs.solve(np.zeros((1, 2)), [1], np.zeros((5, 2)), [1] * 5) is None


def test_gtbb_proposal_box():
    from flatlandia import fine_solver_eval as fse

    ref = np.array([[0.0, 0], [10, 0], [10, 10], [0, 10.5], [20, 20], [-0.4, 5]])
    idx = fse.gtbb_proposal(ref, [1, 2], cam_xy=[0.0, 0.0])  # box [0,10]x[0,10] enlarged 10% -> +-0.5
    assert list(idx) == [0, 1, 2, 3, 5]


def test_summary_counts_thresholds_and_failures():
    import pandas as pd

    from flatlandia import fine_solver_eval as fse

    e = pd.DataFrame({"error_m": [0.1, 0.8, 4.0, 50.0], "error_deg": [1.0, 4.0, 9.0, 90.0],
                      "solvable": [True, True, True, False], "seconds": [0.01] * 4,
                      "error_paper_units_m": [1.0, 2.0, 3.0, 4.0]})
    s = fse.summarise(e)
    assert (s["pct_0.5m_2deg"], s["pct_1m_5deg"], s["pct_5m_10deg"], s["pct_10m_20deg"]) == (25, 50, 75, 75)
    assert s["failure_pct"] == 25 and s["gross_pct"] == 25 and s["median_m"] == pytest.approx(2.4)


def test_camera_prior_keeps_hypotheses_near_known_cameras():
    ref, cls, cam, theta, local, qcls, _ = _scene(seed=5)
    p = bs.solve(local * 0.02, qcls, ref, cls, prior_xy=cam[None] + [[4.0, -3.0]], prior_radius_m=15.0)
    assert np.hypot(p.x - cam[0], p.y - cam[1]) < 1e-6
    far = bs.solve(local * 0.02, qcls, ref, cls, prior_xy=np.array([[500.0, 500.0]]), prior_radius_m=15.0)
    assert far is None  # no pose is allowed where no camera ever stood
