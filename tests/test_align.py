"""Alignment: robust plane, plane angle vs the published one, RANSAC Umeyama similarity."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from conftest import data_root

from flatlandia import geo, scaled_rigid
from flatlandia.data import published
from flatlandia.objects import cloud, principal_plane
from flatlandia.plumbing.errors import InputError

ROOT = data_root()


def _tilted_plane(rng, n=200, outliers=20):
    xy = rng.uniform(-50, 50, size=(n, 2))
    normal = np.array([0.1, -0.2, 1.0])
    normal /= np.linalg.norm(normal)
    r = principal_plane.plane_rotation(normal)
    pts = np.column_stack([xy, rng.normal(0, 0.05, n)]) @ r.T + [3, 4, 5]
    out = rng.uniform(-50, 50, size=(outliers, 3))
    return np.vstack([pts, out]), normal


def test_plane_known_answer_with_outliers():
    rng = np.random.default_rng(0)
    pts, normal = _tilted_plane(rng)
    pl = principal_plane.fit_plane(pts, threshold=0.3)
    assert principal_plane.normal_angle_deg(pl.normal, normal) < 0.2
    assert pl.inliers[:200].mean() > 0.95 and pl.inliers[200:].mean() < 0.2
    r = principal_plane.plane_rotation(pl.normal)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r[:, 2], pl.normal, atol=1e-12)


def test_normal_angle_up_to_sign_and_reflection():
    rpp = np.diag([1.0, 1.0, -1.0])  # a reflection, as most published Rpp are
    assert principal_plane.normal_angle_deg([0, 0, 1], principal_plane.published_normal(rpp)) == pytest.approx(0.0)
    assert principal_plane.normal_angle_deg([0, np.sin(0.1), np.cos(0.1)], [0, 0, -1]) == pytest.approx(np.degrees(0.1))


@pytest.mark.parametrize("reflect", [False, True])
def test_ransac_similarity_known_answer(reflect):
    rng = np.random.default_rng(1)
    src = rng.uniform(-100, 100, size=(40, 2))
    r = geo.rot2(0.8) @ (np.diag([1.0, -1.0]) if reflect else np.eye(2))
    dst = 3.0 * src @ r.T + [500, -200]
    dst[:6] += rng.uniform(100, 200, size=(6, 2))  # outliers
    sim = scaled_rigid.ransac_scaled_rigid(src, dst, threshold=1.0, seed=0)
    assert sim.reflection == reflect
    assert sim.scale == pytest.approx(3.0, rel=1e-9)
    np.testing.assert_allclose(sim.rotation, r, atol=1e-9)
    assert not sim.inliers[:6].any() and sim.inliers[6:].all()


def test_similarity_never_mirrors_a_walk_along_a_street():
    """Camera centres nearly on a line fit a mirror as well as a rotation; without reflections
    (the GPS alignment) the fit stays proper and right, and the least-squares fit is exact."""
    rng = np.random.default_rng(3)
    src = np.column_stack([np.linspace(0, 200, 30), rng.normal(0, 0.5, 30)])
    r = geo.rot2(2.0)
    dst = 0.7 * src @ r.T + [10, 20] + rng.normal(0, 0.2, (30, 2))
    sim = scaled_rigid.ransac_scaled_rigid(src, dst, threshold=2.0, seed=0, allow_reflection=False)
    assert not sim.reflection and sim.inliers.all()
    assert sim.angle_deg() == pytest.approx(np.degrees(2.0), abs=0.5) and sim.scale == pytest.approx(0.7, rel=0.01)
    exact = scaled_rigid.least_squares(src, 0.7 * src @ r.T + [10, 20])
    assert exact.scale == pytest.approx(0.7, rel=1e-9) and np.allclose(exact.rotation, r, atol=1e-9)
    mirrored = scaled_rigid.least_squares(src, 0.7 * src @ (r @ np.diag([1.0, -1.0])).T, allow_reflection=True)
    assert mirrored.reflection and mirrored.scale == pytest.approx(0.7, rel=1e-9)


def test_heading_term_rejects_wrong_headings():
    rng = np.random.default_rng(2)
    src = rng.uniform(-50, 50, size=(30, 2))
    th = 0.5
    dst = src @ geo.rot2(th).T
    hs = rng.uniform(-np.pi, np.pi, 30)
    hd = hs + th
    hd[:5] += np.pi  # five cameras with wrong compass heading
    sim = scaled_rigid.ransac_scaled_rigid(src, dst, threshold=1.0, src_heading=hs, dst_heading=hd)
    assert sim.angle_deg() == pytest.approx(np.degrees(th), abs=1e-6)
    assert not sim.inliers[:5].any() and sim.inliers[5:].all()


def test_bad_input():
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0), np.zeros(10)])
    with pytest.raises(InputError, match="on a line"):
        principal_plane.fit_plane(line, source="cams")
    with pytest.raises(InputError, match="at least 3"):
        principal_plane.fit_plane(np.zeros((2, 3)))
    with pytest.raises(InputError, match="NaN"):
        principal_plane.fit_plane(np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]]))
    with pytest.raises(InputError, match="at least 3"):
        scaled_rigid.ransac_scaled_rigid(np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(InputError, match="NaN"):
        scaled_rigid.ransac_scaled_rigid(np.array([[0, 0], [1, 0], [np.nan, 1.0]]), np.zeros((3, 2)))
    with pytest.raises(InputError, match="coincide"):
        scaled_rigid.ransac_scaled_rigid(np.ones((4, 2)), np.zeros((4, 2)))
    with pytest.raises(InputError, match="but"):
        scaled_rigid.ransac_scaled_rigid(np.eye(3)[:, :2], np.zeros((4, 2)))


# ----------------------------------------------------------------------- real scene 12


@pytest.fixture(scope="module")
def scene12(tmp_path_factory):
    pycolmap = pytest.importorskip("pycolmap")
    d = tmp_path_factory.mktemp("sfm12")
    sfm = ROOT / "maps/12/SfM"
    with zipfile.ZipFile(sfm / "images.zip") as z:
        z.extract("images.bin", d)
    for f in ("cameras.bin", "points3D.bin"):
        (d / f).write_bytes((sfm / f).read_bytes())
    rec = pycolmap.Reconstruction(str(d))
    centres = np.array([im.projection_center() for im in rec.images.values()])
    t = published.read_transformations(ROOT / "maps/12/transformations.json")
    return centres, t


@pytest.mark.slow  # the published data (scene12)
def test_scene12_plane_from_cameras(scene12):
    centres, t = scene12
    assert len(centres) == 49
    pl = principal_plane.fit_plane(centres, source="scene 12 cameras")
    angle = principal_plane.normal_angle_deg(pl.normal, principal_plane.published_normal(t["to_principal_plane"]))
    assert angle < 2.0  # measured 0.57 degrees (target: 2)


@pytest.mark.slow  # the published data (scene12)
def test_scene12_similarity_simulated_gps(scene12):
    centres, t = scene12
    ll = geo.sfm_to_lonlat(centres, t)
    frame = geo.frame_for(ll)
    truth = frame.to_xy(ll)
    rot = principal_plane.plane_rotation(principal_plane.fit_plane(centres).normal)
    src = principal_plane.project_to_plane(centres, rot)
    rng = np.random.default_rng(0)
    gps = truth + rng.normal(0, 5.0, truth.shape)
    out = rng.choice(len(gps), 5, replace=False)
    ang = rng.uniform(0, 2 * np.pi, 5)
    gps[out] += rng.uniform(30, 80, (5, 1)) * np.column_stack([np.cos(ang), np.sin(ang)])
    sim = scaled_rigid.ransac_scaled_rigid(src, gps, threshold=15.0, seed=0)
    err = scaled_rigid.transform_error(sim, src, truth)
    assert not sim.inliers[out].any()
    assert err["reflection_correct"]
    assert err["median_m"] < 5.0 and abs(err["scale_ratio"] - 1) < 0.05 and err["rotation_deg"] < 8


# ----------------------------------------------------------------------- ground plane of class clouds

CLASS_CLOUD_SCENES = ["1", "2", "4", "5", "8", "9", "11", "12", "13", "14", "17", "18"]


def test_irls_plane_known_answer():
    rng = np.random.default_rng(3)
    pts, normal = _tilted_plane(rng, outliers=40)
    pl = principal_plane.irls_plane(pts, scale=0.5)
    assert principal_plane.normal_angle_deg(pl.normal, normal) < 0.3
    assert pl.inliers[:200].mean() > 0.95


def test_ground_plane_bad_input():

    line = np.column_stack([np.arange(30.0), np.zeros(30), np.zeros(30)])
    with pytest.raises(InputError, match="on a line"):
        principal_plane.fit_ground_plane(line, np.array(["manhole"] * 30, dtype=object), 1.0)
    with pytest.raises(InputError, match="classified"):
        principal_plane.fit_ground_plane(np.zeros((5, 3)), np.array([cloud.BACKGROUND] * 5, dtype=object), 1.0)
    with pytest.raises(InputError, match="NaN"):
        principal_plane.fit_ground_plane(np.full((30, 3), np.nan), np.array(["manhole"] * 30, dtype=object), 1.0)
    with pytest.raises(InputError, match="positive"):
        principal_plane.fit_ground_plane(np.zeros((3, 3)), np.array(["sign"] * 3, dtype=object), 0.0)


@pytest.mark.slow  # the published data
def test_ground_plane_all_class_clouds():
    """Our street plane is within 2 degrees of the published one on all 12 class clouds.

    Measured: 0.19 0.86 1.26 1.18 0.38 1.66 1.14 0.86 1.04 0.38 0.47 0.48 degrees (scenes
    1 2 4 5 8 9 11 12 13 14 17 18; 9 and 13 have < 25 ground points and use the fallback).
    """

    angles = {}
    for s in CLASS_CLOUD_SCENES:
        pts, labels = cloud.read_classified_cloud(ROOT / f"maps/{s}/class_segmented_point_cloud.ply")
        t = published.read_transformations(ROOT / f"maps/{s}/transformations.json")
        pl, _ = principal_plane.fit_ground_plane(pts, labels, cloud.metres_per_unit(t), source=s)
        angles[s] = principal_plane.normal_angle_deg(
            pl.normal, principal_plane.published_normal(t["to_principal_plane"])
        )
    assert max(angles.values()) < 2.0, angles
