"""Upper bounds of the reference-map reproduction: single-linkage tree, exact objects, oracle radius,
COLMAP tracks, separability of kept clusters. Known answers on hand-made data, then the real clouds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import data_root

from flatlandia import geo
from flatlandia.data import published
from flatlandia.objects import audit, bounds, cloud, clustering
from flatlandia.plumbing.errors import InputError

ROOT = data_root()


def _line(xs):
    return np.array([[x, 0.0, 0.0] for x in xs])


def test_single_linkage_tree_known_answer():
    pts = _line([0, 1, 2, 10, 11])
    tree = bounds.single_linkage_tree(pts, pts[:, :1], max_radius=9.0)
    nodes = pd.DataFrame({"mean": tree.mean[:, 0], "size": tree.size, "born": tree.born, "dies": tree.dies})
    left = nodes[(nodes["size"] == 3)].iloc[0]
    assert left["mean"] == pytest.approx(1.0) and (left["born"], left["dies"]) == (1.0, 8.0)
    right = nodes[(nodes["size"] == 2) & (nodes["mean"] > 5)].iloc[0]
    assert right["mean"] == pytest.approx(10.5) and (right["born"], right["dies"]) == (1.0, 8.0)
    root = nodes[nodes["size"] == 5].iloc[0]
    assert root["mean"] == pytest.approx(4.8) and root["born"] == 8.0 and np.isinf(root["dies"])
    assert (tree.born[:5] == 0).all() and len(tree.size) == 5 + 4
    # merges beyond max_radius are not made: two roots that never die
    cut = bounds.single_linkage_tree(pts, pts[:, :1], max_radius=5.0)
    assert len(cut.size) == 5 + 3 and np.isinf(cut.dies[cut.size == 3]).all()


def test_exact_objects_known_answer():
    pts = _line([0, 1, 2, 10, 11])
    tree = bounds.single_linkage_tree(pts, pts[:, :2], max_radius=9.0)
    ex = bounds.exact_objects(tree, np.array([[1.0, 0], [5.0, 0], [10.5, 0]]), tol=1e-9, min_size=2)
    assert list(ex["exact"]) == [True, False, True]
    assert (ex.loc[0, "radius_lo"], ex.loc[0, "radius_hi"]) == (1.0, 8.0)
    assert ex.loc[1, "dist"] == pytest.approx(0.2) and np.isnan(ex.loc[1, "radius_lo"])  # nearest: the root 4.8
    # min_size excludes the 2-point node
    assert list(bounds.exact_objects(tree, np.array([[10.5, 0]]), tol=1e-9, min_size=3)["exact"]) == [False]


def test_best_radius_reproduction_known_answer():
    ref = np.array([[0.0, 0], [10, 0]])

    def means(r):  # small radius: both objects and a spurious one; large: one merged cluster
        return np.array([[0.01, 0], [10.3, 0], [30, 0]]) if r < 1 else np.array([[5.0, 0]])

    t = bounds.best_radius_reproduction(means, ref, np.array([0.5, 2.0]))
    assert list(t["clusters"]) == [3, 1]
    assert list(t["within_0.05m"]) == [1, 0] and list(t["within_0.5m"]) == [2, 0]


def test_feature_auc_known_answer():
    f = pd.DataFrame({"sep": [1, 2, 3, 10, 11, 12], "flat": [1, 1, 1, 1, 1, 1]})
    auc = bounds.feature_auc(f, np.array([0, 0, 0, 1, 1, 1], bool))
    assert auc == {"sep": 1.0, "flat": 0.5}
    assert np.isnan(bounds.feature_auc(f, np.ones(6, bool))["sep"])


@pytest.mark.slow  # the published data
def test_read_colmap_tracks_real_and_bad(tmp_path):
    xyz, images = bounds.read_colmap_tracks(ROOT / "maps/12/SfM/points3D.bin")
    pts, _ = cloud.read_classified_cloud(ROOT / "maps/12/class_segmented_point_cloud.ply")
    assert len(xyz) == 9329 and len(images) == 9329
    from scipy.spatial import cKDTree

    assert cKDTree(xyz).query(pts)[0].max() < 1e-9  # the class cloud is the SfM point set
    lengths = np.array([len(i) for i in images])
    assert lengths.min() >= 2 and lengths.max() <= 51  # a track spans 2+ of the 49 images
    bad = tmp_path / "points3D.bin"
    bad.write_bytes(b"\x05\x00\x00\x00\x00\x00\x00\x00 short")
    with pytest.raises(InputError, match="points3D"):
        bounds.read_colmap_tracks(bad)
    with pytest.raises(InputError, match="missing"):
        bounds.read_colmap_tracks(tmp_path / "absent.bin")


def _scene(scene):
    maps = ROOT / "maps" / scene
    pts, labels = cloud.read_classified_cloud(maps / "class_segmented_point_cloud.ply")
    t = published.read_transformations(maps / "transformations.json")
    ref_ll, ref_cl = published.read_reference_map(ROOT / "individual_reference_maps" / f"map_{scene}.json")
    frame = geo.frame_for(ref_ll)
    return (
        pts,
        labels,
        cloud.metres_per_unit(t),
        frame.to_xy(geo.sfm_to_lonlat(pts, t)),
        frame.to_xy(ref_ll),
        ref_cl,
    )


@pytest.mark.slow  # the published data (via _scene)
def test_dbscan_objects_are_tree_nodes_real():
    """Scene 12: every object of the workflow's clustering is a node of its colour's single-linkage
    tree, alive at the radius used (the tree enumerates what any radius can give)."""
    pts, labels, mpu, xy, _, _ = _scene("12")
    p = clustering.ClusterParams()
    for name in sorted(set(labels) - {cloud.BACKGROUND}):
        ci = np.flatnonzero(labels == name)
        tree = bounds.single_linkage_tree(pts[ci], xy[ci], max_radius=2.5 / mpu)
        eps = p.eps_for(name) / mpu
        for c in clustering._clusters_of_class(pts[ci], mpu, p, p.eps_for(name)):
            ex = bounds.exact_objects(tree, xy[ci[c]].mean(0)[None], tol=1e-9)
            assert ex.loc[0, "exact"] and ex.loc[0, "size"] == len(c)
            assert ex.loc[0, "radius_lo"] <= eps < ex.loc[0, "radius_hi"]


@pytest.mark.slow  # the published data (via _scene)
def test_published_colours_scene2_real():
    """Scene 2: 59 published objects are the exact mean of a cluster of one colour; 16 of them
    have a nearest coloured point of another colour (the audit used to match them wrongly)."""
    pts, labels, mpu, xy, ref_xy, ref_cl = _scene("2")
    fg = labels != cloud.BACKGROUND
    nearest = audit.published_macro_classes(ref_xy, ref_cl, xy[fg], labels[fg])
    exact = bounds.published_colours(
        ref_xy,
        np.full(len(ref_xy), "?", dtype=object),
        pts[fg],
        labels[fg],
        xy[fg],
        max_radius=audit.EXACT_SEARCH_RADIUS_M / mpu,
    )
    made = exact != "?"
    assert made.sum() == 59
    assert (exact[made] != nearest[made]).sum() == 16
    both = audit.published_macro_classes(
        ref_xy, ref_cl, xy[fg], labels[fg], cloud_points=pts[fg], exact_radius=audit.EXACT_SEARCH_RADIUS_M / mpu
    )
    assert (both[made] == exact[made]).all() and (both[~made] == nearest[~made]).all()
