import numpy as np
import pytest

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.data import published, recover, registration

MPD = (73_000.0, 111_200.0)  # metres per degree (lon, lat) near 49 N


def _synthetic(seed=0, n_ref=60, n_local=5):
    rng = np.random.default_rng(seed)
    ref_units = rng.uniform(0, 1.5, size=(n_ref, 2))  # unit space, ~ 280 m wide
    cam, theta = np.array([0.7, 0.6]), 0.8
    pick = rng.choice(n_ref, n_local, replace=False)
    local = (ref_units[pick] - cam) @ geo.rot2(theta)
    return ref_units, pick, cam, theta, local


def test_register_recovers_known_pose_and_matches():
    ref, pick, cam, theta, local = _synthetic()
    rec = registration.register(local, registration.PairIndex(ref), MPD)
    assert rec is not None
    assert rec.best.ref_idx == tuple(pick)
    assert np.allclose(rec.best.cam, cam, atol=1e-9)
    assert rec.best.theta == pytest.approx(theta, abs=1e-9)
    assert rec.best.max_m < 1e-6


def test_register_returns_none_when_nothing_fits():
    ref, _, _, _, local = _synthetic()
    local = local * 1.3  # wrong scale: no rigid copy exists
    assert registration.register(local, registration.PairIndex(ref), MPD) is None


def test_symmetric_map_is_flagged_ambiguous_and_classes_resolve_it():
    tri = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.2]])
    ref = np.vstack([tri, tri + [1.0, 1.0]])  # two congruent triangles
    classes = np.array([1, 2, 3, 4, 5, 6])
    local = (tri - [-0.1, -0.1]) @ geo.rot2(0.3)
    rec = registration.register(local, registration.PairIndex(ref), MPD)
    assert len(rec.others) == 1 and rec.others[0].rms_m < 1e-6
    assert registration.classify_ambiguity(rec, classes) == "unresolved"
    same = np.array([1, 2, 3, 1, 2, 3])
    assert registration.classify_ambiguity(rec, same) == "same_classes"
    # knowing the query's classes makes the registration unique
    rec2 = registration.register(
        local, registration.PairIndex(ref), MPD, local_classes=np.array([4, 5, 6]), ref_classes=classes
    )
    assert rec2.best.ref_idx == (3, 4, 5) and not rec2.others


def test_near_tie_resolved_by_exact_residual():
    tri = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.2]])
    nudge = 0.03 / (geo.UNIT_DEG * MPD[1])  # 3 cm in unit space
    ref = np.vstack([tri, tri[2] + [0.0, nudge]])  # a second object 3 cm from the third
    local = tri @ geo.rot2(0.0)
    rec = registration.register(local, registration.PairIndex(ref), MPD)
    assert rec.best.ref_idx == (0, 1, 2)
    assert registration.classify_ambiguity(rec, np.array([1, 2, 3, 4])) == "exact_fit"


@pytest.mark.slow  # the published data (all_local_maps)
def test_all_published_queries_recovered_and_consistent(flat_root, all_local_maps):
    """Every published GT local map is recovered, and re-deriving it from the pose gives it back."""
    n, worst_res, worst_map = 0, 0.0, 0.0
    unresolved = 0
    for scene in sorted(all_local_maps, key=int):
        lonlat, classes = published.read_reference_map(
            flat_root / f"individual_reference_maps/map_{scene}.json", len(CLASSES)
        )
        local = published.read_local_maps(flat_root / "local_maps.json", scene)
        rec = recover.recover_scene(scene, lonlat, classes, local)
        assert rec["recovered"].all(), scene
        n += len(rec)
        worst_res = max(worst_res, rec["residual_m"].max())
        unresolved += int((rec["resolution"] == "unresolved").sum())
        for r in rec.itertuples():
            cam = np.array([r.lon, r.lat])
            pub = (2 / geo.TO_FLATLANDIA) * (lonlat[list(r.ref_idx)] - cam) @ geo.rot2(np.radians(r.theta_lonlat_deg))
            worst_map = max(worst_map, np.abs(pub - local[r.token]["GT"]).max())
    assert n == 2135
    assert worst_res < 0.01  # metres
    assert worst_map < 1e-6  # local-map units (1 unit ~ 100-190 m)
    assert unresolved <= 10


@pytest.mark.slow  # the published data (flat_root)
def test_recovered_scene12_cameras_match_sfm_poses(flat_root, tmp_path):
    """Scene 12 ships images.bin: its SfM camera centres through the chain equal recovered poses."""
    import zipfile

    import pycolmap

    sfm = flat_root / "maps/12/SfM"
    for f in ("cameras.bin", "points3D.bin"):
        (tmp_path / f).write_bytes((sfm / f).read_bytes())
    with zipfile.ZipFile(sfm / "images.zip") as z:
        name = next(n for n in z.namelist() if n.endswith("images.bin"))
        (tmp_path / "images.bin").write_bytes(z.read(name))
    model = pycolmap.Reconstruction(str(tmp_path))
    t = published.read_transformations(flat_root / "maps/12/transformations.json")
    centres = {img.name.rsplit(".", 1)[0]: img.projection_center() for img in model.images.values()}
    lonlat, classes = published.read_reference_map(flat_root / "individual_reference_maps/map_12.json")
    rec = recover.recover_scene("12", lonlat, classes, published.read_local_maps(flat_root / "local_maps.json", "12"))
    frame = geo.frame_for(lonlat)
    checked = 0
    for r in rec.itertuples():
        if r.token in centres:
            ll = geo.sfm_to_lonlat(centres[r.token][None], t)
            d = np.linalg.norm(frame.to_xy(ll) - frame.to_xy(np.array([[r.lon, r.lat]])))
            assert d < 0.01
            checked += 1
    assert checked == len(rec) >= 1
