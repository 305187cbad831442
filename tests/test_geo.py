import numpy as np
import pytest
from pyproj import Geod

from flatlandia import geo
from flatlandia.data import published


def test_metric_frame_round_trip_and_known_distance():
    frame = geo.MetricFrame(lon0=2.37, lat0=48.9)
    ll = np.array([[2.37, 48.9], [2.371, 48.9], [2.37, 48.901]])
    xy = frame.to_xy(ll)
    assert np.allclose(xy[0], 0, atol=1e-6)
    assert np.allclose(frame.to_lonlat(xy), ll, atol=1e-10)
    # 0.001 deg of latitude ~ 111.2 m, of longitude at 48.9 N ~ 73.3 m (WGS84 geodesics)
    geod = Geod(ellps="WGS84")
    for k in (1, 2):
        _, _, d = geod.inv(ll[0, 0], ll[0, 1], ll[k, 0], ll[k, 1])
        assert np.linalg.norm(xy[k] - xy[0]) == pytest.approx(d, abs=0.01)
    mx, my = frame.metres_per_degree()
    assert mx / my == pytest.approx(np.cos(np.radians(48.9)), rel=3e-3)


@pytest.mark.slow  # the published data (flat_root)
def test_known_distance_between_two_real_objects(flat_root):
    lonlat, _ = published.read_reference_map(flat_root / "individual_reference_maps/map_12.json")
    frame = geo.frame_for(lonlat)
    xy = frame.to_xy(lonlat)
    geod = Geod(ellps="WGS84")
    i, j = 0, int(np.argmax(np.linalg.norm(lonlat - lonlat[0], axis=1)))
    _, _, d = geod.inv(lonlat[i, 0], lonlat[i, 1], lonlat[j, 0], lonlat[j, 1])
    assert d > 100  # far apart objects, so the test means something
    assert np.linalg.norm(xy[i] - xy[j]) == pytest.approx(d, abs=0.02)


def test_heading_conversion_matches_projected_direction():
    frame = geo.MetricFrame(lon0=16.38, lat0=48.2)
    theta = np.radians(30.0)
    start = np.array([[frame.lon0, frame.lat0]])
    end = start + 1e-4 * np.array([[np.cos(theta), np.sin(theta)]])
    d = frame.to_xy(end) - frame.to_xy(start)
    assert float(frame.heading_to_metric(theta)) == pytest.approx(np.arctan2(d[0, 1], d[0, 0]), abs=1e-4)
    # east, north and west stay where they are
    assert np.allclose(frame.heading_to_metric(np.array([0.0, np.pi / 2])), [0.0, np.pi / 2], atol=1e-9)


def test_local_world_inverse_and_rigid_fit():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(6, 2)) * 20
    cam, theta = np.array([3.0, -4.0]), 1.2
    local = geo.world_to_local(pts, cam, theta)
    assert np.allclose(geo.local_to_world(local, cam, theta), pts)
    # camera looks along +x: a point straight ahead has y == 0 and x > 0
    ahead = cam + 10 * np.array([np.cos(theta), np.sin(theta)])
    assert np.allclose(geo.world_to_local(ahead[None], cam, theta), [[10.0, 0.0]])
    th, t = geo.rigid_fit_2d(local, pts)
    assert th == pytest.approx(theta) and np.allclose(t, cam)


@pytest.mark.slow  # the published data (flat_root)
def test_sfm_chain_handles_reflections(flat_root):
    t = published.read_transformations(flat_root / "maps/12/transformations.json")
    rpp = np.asarray(t["to_principal_plane"])
    assert np.linalg.det(rpp) == pytest.approx(-1, abs=1e-6)  # scene 12's plane rotation is a reflection
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    ll = geo.sfm_to_lonlat(pts, t)
    s = t["to_mapillary"]["scaling_factor_sfm_to_gps"]
    assert np.allclose(ll[0], t["to_mapillary"]["translation"][0][:2])
    # planar part of the displacement is scaled isotropically by s (rotation/reflection keeps length)
    planar = (pts[1] @ rpp)[:2]
    assert np.linalg.norm(ll[1] - ll[0]) == pytest.approx(s * np.linalg.norm(planar), rel=1e-9)
