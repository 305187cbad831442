"""Objects stage: clustering, boxes, PLY I/O, label transfer and the reproduction audit."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import data_root

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.data import published
from flatlandia.objects import audit, cloud, clustering, labels, principal_plane
from flatlandia.plumbing.errors import InputError

ROOT = data_root()
CLASS_CLOUD_SCENES = ["1", "2", "4", "5", "8", "9", "11", "12", "13", "14", "17", "18"]


def _blob(rng, centre, n, sd=0.1):
    return rng.normal(centre, sd, size=(n, 3))


def test_clusters_two_classes_known_answer():
    rng = np.random.default_rng(0)
    # SfM units = 0.5 m: two sign blobs 10 m apart, one pole blob, one isolated pole point, background
    a, b, c = _blob(rng, [0, 0, 0], 20), _blob(rng, [20, 0, 0], 15), _blob(rng, [0, 20, 0], 8)
    lone = np.array([[40.0, 40, 0]])
    bg = rng.uniform(-50, 50, size=(50, 3))
    pts = np.vstack([a, b, c, lone, bg])
    labels = np.array(["sign"] * 35 + ["pole"] * 9 + [cloud.BACKGROUND] * 50, dtype=object)
    df = clustering.cluster_objects(pts, labels, metres_per_unit=0.5)
    assert list(df.columns) == clustering.OBJECT_COLUMNS
    assert sorted(df["n_points"]) == [8, 15, 20]
    got = df.sort_values("n_points")[["cx", "cy", "cz"]].to_numpy()
    np.testing.assert_allclose(got, [c.mean(0), b.mean(0), a.mean(0)], atol=1e-12)
    assert set(df["macro_class"]) == {"sign", "pole"}


def test_split_merged_neighbours():
    rng = np.random.default_rng(1)
    # two poles 1.5 m apart joined by a thin bridge: one DBSCAN cluster at eps 1 m, split at 0.5 m
    p1 = _blob(rng, [0, 0, 0], 30, 0.05)
    p2 = _blob(rng, [4.0, 0, 0], 30, 0.05)
    bridge = np.column_stack([np.linspace(0.3, 3.7, 5), np.zeros(5), np.zeros(5)])
    pts = np.vstack([p1, p2, bridge])
    labels = np.array(["pole"] * len(pts), dtype=object)
    merged = clustering.cluster_objects(pts, labels, 1.0, clustering.ClusterParams(eps_m=1.0, eps_m_by_class={}))
    assert len(merged) == 1
    split = clustering.cluster_objects(
        pts, labels, 1.0, clustering.ClusterParams(eps_m=1.0, eps_m_by_class={}, split_extent_m=3.0)
    )
    assert len(split) == 2
    # the default pole radius (0.4 m) already separates them: poles are clustered tighter
    assert len(clustering.cluster_objects(pts, labels, 1.0)) == 2


def test_instance_parts_known_answer():
    pts = np.array(
        [[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [1.0, 0, 0], [1.1, 0, 0], [1.2, 0, 0], [0.05, 0, 0], [1.15, 0, 0.0]]
    )
    members = np.arange(8)
    # image 1: instance 1 covers points 0-2, instance 2 points 3-4; image 2: one instance on 4 and 5
    # (joins 5 to 3-4 across images); point 6 is seen on no instance, point 7 on a lone instance
    obs_point = np.array([0, 1, 2, 3, 4, 4, 5, 7])
    obs_key = np.array([(1 << 32) + 1] * 3 + [(1 << 32) + 2] * 2 + [(2 << 32) + 9] * 2 + [(2 << 32) + 4])
    parts = clustering.instance_parts(members, pts, obs_point, obs_key, min_points=3)
    assert sorted(map(sorted, map(list, parts))) == [[0, 1, 2, 6], [3, 4, 5, 7]]  # 6, 7 join their nearest part
    # one instance only, or none seen: the cluster stays whole
    assert [list(p) for p in clustering.instance_parts(members, pts, obs_point[:3], obs_key[:3], 3)] == [list(members)]
    assert [list(p) for p in clustering.instance_parts(members, pts, np.array([99]), np.array([5]), 3)] == [
        list(members)
    ]
    # members given in any order, as global indices of a larger cloud
    shuffled = np.array([17, 12, 15, 10, 11, 13, 14, 16])
    big = np.zeros((18, 3))
    big[shuffled] = pts[np.arange(8)]
    parts = clustering.instance_parts(shuffled, big, shuffled[obs_point], obs_key, min_points=3)
    assert sorted(map(sorted, map(list, parts))) == sorted(sorted(shuffled[g]) for g in ([0, 1, 2, 6], [3, 4, 5, 7]))


def test_cluster_objects_split_by_instances():
    rng = np.random.default_rng(2)
    # two signs 1 m apart: one cluster at the sign radius; the image instances separate them
    a, b = _blob(rng, [0, 0, 0], 20, 0.05), _blob(rng, [1.0, 0, 0], 20, 0.05)
    pts = np.vstack([a, b])
    labels = np.array(["sign"] * 40, dtype=object)
    assert len(clustering.cluster_objects(pts, labels, 1.0)) == 1
    obs_point = np.arange(40)
    obs_key = np.where(obs_point < 20, 7, 8)

    def split(members):
        return clustering.instance_parts(members, pts, obs_point, obs_key, 3)

    df, member = clustering.cluster_objects(pts, labels, 1.0, split=split, with_members=True)
    got = df.sort_values("cx")[["cx", "cy", "cz"]].to_numpy()
    np.testing.assert_allclose(got, [a.mean(0), b.mean(0)], atol=1e-12)
    # every point belongs to the part of its instance, whatever the boxes' overlap
    first = df.sort_values("cx")["object_id"].to_numpy()
    assert (member[:20] == first[0]).all() and (member[20:] == first[1]).all()


def test_per_class_radius():
    p = clustering.ClusterParams()
    assert p.eps_for("pole") == pytest.approx(0.40) and p.eps_for("sign") == pytest.approx(1.24)
    assert p.eps_for("manhole") == p.eps_for("traffic_light") == pytest.approx(0.88)
    # two sign points 1.0 m apart join (radius 1.24 m); the same two as poles do not (0.4 m)
    pts = np.array([[0, 0, 0], [1.0, 0, 0], [0.5, 0.1, 0]])
    assert len(clustering.cluster_objects(pts, np.array(["sign"] * 3, dtype=object), 1.0)) == 1
    assert len(clustering.cluster_objects(pts, np.array(["pole"] * 3, dtype=object), 1.0)) == 0
    with pytest.raises(ValueError):
        clustering.cluster_objects(
            pts, np.array(["sign"] * 3, dtype=object), 1.0, clustering.ClusterParams(eps_m_by_class={"pole": 0})
        )


def test_oriented_box_known_answer():
    rng = np.random.default_rng(2)
    local = rng.uniform(-1, 1, size=(500, 3)) * [4, 1, 0.25]
    rot = geo.rot2(0.7)
    r3 = np.eye(3)
    r3[:2, :2] = rot
    pts = local @ r3.T + [10, 5, 1]
    centre, extent, r = clustering.oriented_box(pts)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(extent, [8, 2, 0.5], atol=0.05)
    np.testing.assert_allclose(centre, [10, 5, 1], atol=0.05)
    assert abs(abs(r[:, 0] @ r3[:, 0]) - 1) < 1e-3


def test_oriented_box_where_open3d_cannot():
    """Why the PCA box stays ours: open3d's OrientedBoundingBox needs more than 3 points (435 of
    the 1628 published-scene clusters have exactly 3) and takes the PCA of the convex hull, not of
    the points (main axes 0.35 deg apart at the median, 5.3 deg at the 90th percentile,
    /work/notes/obb_compare.txt). Our box of 3 points is flat and holds them."""
    import open3d as o3d

    three = np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0.5]])
    with pytest.raises(RuntimeError):
        o3d.geometry.OrientedBoundingBox.create_from_points(o3d.utility.Vector3dVector(three))
    centre, extent, r = clustering.oriented_box(three)
    assert extent[2] == pytest.approx(0.0, abs=1e-12) and extent[0] > extent[1] > 0
    local = (three - centre) @ r
    assert (np.abs(local) <= extent / 2 + 1e-12).all()


def test_boxes_ply_round_trip(tmp_path):
    import open3d as o3d

    rng = np.random.default_rng(3)
    pts = np.vstack([_blob(rng, [0, 0, 0], 10), _blob(rng, [30, 0, 0], 10)])
    df = clustering.cluster_objects(pts, np.array(["light"] * 20, dtype=object), 0.5)
    out = tmp_path / "objects.ply"
    clustering.write_boxes_ply(df, out)
    mesh = o3d.io.read_triangle_mesh(str(out))
    assert len(mesh.vertices) == 16 and len(mesh.triangles) == 24
    v = np.asarray(mesh.vertices)
    for k, row in enumerate(df.itertuples(index=False)):
        np.testing.assert_allclose(v[8 * k : 8 * k + 8].mean(0), [row.box_cx, row.box_cy, row.box_cz], atol=1e-9)
    # every cluster point lies inside its box
    obb = o3d.geometry.OrientedBoundingBox.create_from_points(o3d.utility.Vector3dVector(v[:8]))
    assert len(obb.get_point_indices_within_bounding_box(o3d.utility.Vector3dVector(pts[:10]))) >= 9


def test_ascii_ply_with_class_id(tmp_path):
    p = tmp_path / "c.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar class_id\nend_header\n0 0 0 24\n1 1 1 255\n"
    )
    pts, labels = cloud.read_classified_cloud(p)
    assert pts.shape == (2, 3) and list(labels) == ["light", cloud.BACKGROUND]


def test_bad_input(tmp_path):
    with pytest.raises(InputError, match="no classified points"):
        clustering.cluster_objects(
            np.zeros((5, 3)), np.array([cloud.BACKGROUND] * 5, dtype=object), 1.0, source="x.ply"
        )
    with pytest.raises(InputError, match="NaN"):
        clustering.cluster_objects(np.array([[np.nan, 0, 0], [0, 0, 0]]), np.array(["sign"] * 2, dtype=object), 1.0)
    # a class with a single point: a documented empty result, not a crash
    one = clustering.cluster_objects(np.zeros((1, 3)), np.array(["sign"], dtype=object), 1.0)
    assert len(one) == 0 and list(one.columns) == clustering.OBJECT_COLUMNS
    bad = tmp_path / "bad.ply"
    bad.write_text("not a ply")
    with pytest.raises(InputError, match="not a PLY file"):
        cloud.read_classified_cloud(bad)
    weird = tmp_path / "weird.ply"
    weird.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n0 0 0 1 2 3\n"
    )
    with pytest.raises(InputError, match="colour"):
        cloud.read_classified_cloud(weird)
    with pytest.raises(InputError, match="missing"):
        cloud.read_classified_cloud(tmp_path / "absent.ply")


def test_class_prior_uses_other_scenes_only():
    light = cloud.MACRO_BY_NAME["light"].classes[0]
    store, adv = (
        CLASSES.index("object--sign--store"),
        CLASSES.index("object--sign--advertisement"),
    )
    prior = labels.class_prior([np.array([store, store, adv]), np.array([adv])])
    assert prior["sign"] == adv  # 2 vs 2: a tie goes to the lower id (advertisement 15 < store 17)
    prior = labels.class_prior([np.array([store, store, adv])])
    assert prior["sign"] == store and prior["light"] == light


def test_audit_known_answer():
    ref = np.array([[0, 0], [10, 0], [20, 0.0]])
    ours = np.array([[0.01, 0], [10.3, 0], [23, 0], [50, 50.0]])
    row = audit.audit_scene(
        "t", ours, np.array(["a", "a", "a", "a"], dtype=object), ref, np.array(["a", "a", "a"], dtype=object)
    )
    assert (row["within_0.05m"], row["within_0.5m"], row["within_2m"], row["matched"]) == (1, 2, 2, 2)
    assert row["extra"] == 2 and row["published"] == 3 and row["ours"] == 4
    # a different macro-class never matches
    row = audit.audit_scene("t", ours[:1], np.array(["b"], dtype=object), ref[:1], np.array(["a"], dtype=object))
    assert row["matched"] == 0


# ----------------------------------------------------------------------- real published data


@pytest.mark.slow  # the published data
def test_macro_table_matches_measurement():
    """The MACRO_CLASSES table agrees with the colours measured on scene 12 and 13."""
    for scene in ("12", "13"):
        pts, labels = cloud.read_classified_cloud(ROOT / f"maps/{scene}/class_segmented_point_cloud.ply")
        t = published.read_transformations(ROOT / f"maps/{scene}/transformations.json")
        ll, cl = published.read_reference_map(ROOT / f"individual_reference_maps/map_{scene}.json")
        counts = cloud.colour_class_counts(geo.sfm_to_lonlat(pts, t), labels, ll, cl, geo.frame_for(ll))
        agree = sum(r.count for r in counts.itertuples() if cloud.MACRO_OF_CLASS[r.class_id] == r.macro_class)
        assert agree / counts["count"].sum() >= 0.9


@pytest.fixture(scope="module")
def audit_rows():
    rows = [audit.audit_published_scene(ROOT, s)[0] for s in CLASS_CLOUD_SCENES]
    return pd.DataFrame(rows)


@pytest.mark.slow  # the published data (audit_rows)
def test_reproduction_real(audit_rows):
    df = audit_rows
    assert df["published"].sum() == 854
    pub = df["published"].sum()
    # Measured with the default ClusterParams (DBSCAN 1.24 m, poles 0.40 m, manholes and traffic
    # lights 0.88 m, >= 3 points, no split): 619 exact (72.5%), 707 within 0.5 m (82.8%),
    # 739 within 2 m. The target (90%, <= 10% extra) is not reached (module notes).
    assert df["within_0.05m"].sum() / pub >= 0.72
    assert df["within_0.5m"].sum() / pub >= 0.82
    # without scene 2 (its cloud is 99.7% coloured): 85.6% within 0.5 m, 19.6% extra
    rest = df[df["scene"] != "2"]
    assert rest["within_0.5m"].sum() / rest["published"].sum() >= 0.85
    assert rest["extra"].sum() / rest["published"].sum() <= 0.20
    # scenes whose published map keeps (almost) every cluster: few extras, >= 85% reproduced
    for s in ("12", "14", "18"):
        r = df[df["scene"] == s].iloc[0]
        assert r["within_0.5m"] / r["published"] >= 0.85 and r["extra"] <= 3


@pytest.mark.xfail(
    reason="reproduction target out of reach from the clouds: best radius per scene and class with the "
    "answer gives 87.5%; per-object splits and the kept clusters of scenes 2 and 4 come from the "
    "images (benchmarks/reproduction_bounds.py)",
    strict=True,
)
@pytest.mark.slow  # the published data (audit_rows)
def test_reproduction_target(audit_rows):
    df = audit_rows
    assert df["within_0.5m"].sum() / df["published"].sum() >= 0.9
    assert (df["ours"].sum() - df["within_0.5m"].sum()) / df["published"].sum() <= 0.1


# ----------------------------------------------------------------------- planes (open3d RANSAC, our IRLS)


def test_fit_plane_finds_the_true_inliers():
    """open3d's seeded RANSAC picks exactly the points on the plane; the normal equals an
    independent SVD fit on them, and a rerun gives the same plane."""
    rng = np.random.default_rng(4)
    normal = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    rot = principal_plane.plane_rotation(normal)
    on = np.column_stack([rng.uniform(-50, 50, (200, 2)), rng.normal(0, 0.05, 200)]) @ rot.T + [3, 4, 5]
    off = rng.uniform(-50, 50, (20, 3))
    off = off[np.abs((off - [3, 4, 5]) @ normal) > 1.0]
    pts = np.vstack([on, off])
    pl = principal_plane.fit_plane(pts, threshold=0.3)
    assert pl.inliers[:200].all() and not pl.inliers[200:].any()
    svd = np.linalg.svd(on - on.mean(0))[2][2]
    assert principal_plane.normal_angle_deg(pl.normal, svd) < 1e-9
    assert principal_plane.normal_angle_deg(pl.normal, normal) < 0.1
    np.testing.assert_array_equal(principal_plane.fit_plane(pts, threshold=0.3).normal, pl.normal)


@pytest.mark.slow  # the published data
def test_fit_plane_scene12_cameras_unchanged(tmp_path):
    """The camera plane of scene 12 (the only published scene that ships images.bin) is today's:
    the hand-written RANSAC gave normal (0.008596042, -0.997955606, 0.063330213) with 46 of 49
    inliers (/work/notes/open3d_before.txt); open3d's segment_plane must stay within 0.05 deg."""
    import zipfile

    pycolmap = pytest.importorskip("pycolmap")
    sfm = ROOT / "maps/12/SfM"
    with zipfile.ZipFile(sfm / "images.zip") as z:
        z.extract("images.bin", tmp_path)
    for f in ("cameras.bin", "points3D.bin"):
        (tmp_path / f).write_bytes((sfm / f).read_bytes())
    rec = pycolmap.Reconstruction(str(tmp_path))
    centres = np.array([im.projection_center() for im in rec.images.values()])
    pl = principal_plane.fit_plane(centres, source="scene 12 cameras")
    assert principal_plane.normal_angle_deg(pl.normal, [0.008596042, -0.997955606, 0.063330213]) < 0.05
    assert pl.inliers.sum() == 46


#: Today's street planes (Cauchy IRLS, fit_ground_plane with the default settings) of the 12 class
#: clouds, produced by /work/notes/open3d_check.py before the open3d change. open3d's
#: segment_plane at the same scale is 0.0-26 deg off them (/work/notes/plane_compare.txt), so the
#: IRLS fit stays; this pins it.
GROUND_NORMALS = {
    "1": [0.133852016, -0.979814224, -0.148484762],
    "2": [0.09896308, -0.994126488, 0.043804505],
    "4": [-0.071696257, -0.997019477, 0.028492259],
    "5": [-0.178432265, 0.981032236, -0.075747462],
    "8": [0.046518688, 0.998094211, -0.040545738],
    "9": [-0.042652896, 0.999027243, -0.011193703],
    "11": [-0.071377251, -0.996407432, -0.045579795],
    "12": [0.013276105, -0.998503947, 0.053043491],
    "13": [-0.028021388, -0.954208655, 0.297826536],
    "14": [0.053418439, 0.980423861, -0.189513912],
    "17": [0.018030292, 0.985648084, -0.167847443],
    "18": [0.052563104, 0.987378282, -0.149402974],
}


@pytest.mark.parametrize("scene", CLASS_CLOUD_SCENES)
@pytest.mark.slow  # the published data
def test_ground_plane_unchanged(scene):
    pts, lab = cloud.read_classified_cloud(ROOT / f"maps/{scene}/class_segmented_point_cloud.ply")
    t = published.read_transformations(ROOT / f"maps/{scene}/transformations.json")
    pl, _ = principal_plane.fit_ground_plane(pts, lab, cloud.metres_per_unit(t), source=scene)
    assert principal_plane.normal_angle_deg(pl.normal, GROUND_NORMALS[scene]) < 0.05
