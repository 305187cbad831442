"""Depth backends of images-scene local maps: per-image scaling of monocular depth, lifting, errors."""

from __future__ import annotations

import numpy as np
import pytest

from flatlandia.images import depth
from flatlandia.images.image_queries import View
from flatlandia.plumbing.errors import InputError


def _view():
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    return View("a.jpg", K, np.eye(3), np.zeros(3), 640, 480, np.zeros(0, np.int64), np.zeros((0, 2)))


@pytest.mark.parametrize("inverse", [True, False])
def test_scale_is_recovered_despite_outliers(inverse):
    rng = np.random.default_rng(0)
    d = rng.uniform(3, 40, 200)
    pred = 2.5 / d if inverse else d / 7.0
    pred[:30] *= rng.uniform(0.2, 5, 30)  # depth-edge outliers
    a = depth.fit_scale(pred, d, inverse)
    assert a == pytest.approx(2.5 if inverse else 7.0, rel=1e-9)
    assert np.allclose(depth.scaled_depth(pred[30:], a, inverse), d[30:])


def test_scale_without_usable_points_is_nan():
    assert np.isnan(depth.fit_scale(np.array([0.0, -1.0]), np.array([5.0, 5.0]), True))


def test_lift_box_puts_the_centre_at_the_median_depth():
    v = _view()
    dm = np.full((480, 640), np.nan)
    dm[200:280, 300:340] = 12.0
    dm[200:210, 300:340] = 90.0  # a sliver of background inside the box
    X = depth.lift_box(v, [300, 200, 340, 280], dm)
    assert np.allclose(X, [0.0, 0.0, 12.0])  # box centre (320, 240) is the principal point
    assert depth.lift_box(v, [0, 0, 10, 10], dm) is None  # no depth inside: no point


def test_lifted_point_projects_back_onto_the_box_centre_at_its_depth():
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))  # a rotation
    K = np.array([[700.0, 0, 300], [0, 710.0, 250], [0, 0, 1]])
    v = View("b.jpg", K, R, np.array([0.3, -1.2, 4.0]), 640, 480, np.zeros(0, np.int64), np.zeros((0, 2)))
    X = depth.lift_box(v, [410.5, 120.0, 450.5, 200.0], np.full((480, 640), 7.5))
    cam = R @ X + v.t
    uv = (K @ cam)[:2] / cam[2]
    assert cam[2] == pytest.approx(7.5) and np.allclose(uv, [430.5, 160.0])


def test_monocular_backend_needs_a_local_checkpoint(tmp_path):
    with pytest.raises(InputError, match="local checkpoint folder"):
        depth.make_lifter("transformers", {}, weights=None)
    with pytest.raises(InputError, match="no config.json"):
        depth.make_lifter("transformers", {}, weights=str(tmp_path))
    with pytest.raises(InputError, match="unknown depth backend"):
        depth.make_lifter("lidar", {})
