"""The city stage: tiled maps keep ids, geometry and priors; the index finds the only region
that explains a query; synthetic tiles keep a scene's statistics without copying it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from flatlandia import solver
from flatlandia.city import index, search, simulate, tiling
from flatlandia.data import localmaps
from flatlandia.solver import priors

# one street corner: classes and positions in the frame of a camera at the origin looking along +x
CORNER = [(1, 10.0, 3.0), (2, 15.0, -4.0), (3, 20.0, 6.0), (1, 25.0, -2.0)]


def local_map(xy, cam, theta):
    """Objects seen from a camera (x along its heading, y to its left)."""
    c, s = np.cos(theta), np.sin(theta)
    d = np.asarray(xy, float) - cam
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def distances(p):
    return np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1))


def signed_area(p):
    """Twice the signed area of the first three points: its sign is the handedness."""
    (ax, ay), (bx, by) = p[1] - p[0], p[2] - p[0]
    return ax * by - ay * bx


def scene(name, objects, views):
    """A scene's reference map and training views: ``objects`` (class, x, y), ``views`` (x, y,
    heading in degrees, the object ids each saw)."""
    ref = pd.DataFrame(
        {
            "scene": name,
            "obj_idx": np.arange(len(objects)),
            "class_id": [c for c, _, _ in objects],
            "x_m": [x for _, x, _ in objects],
            "y_m": [y for _, _, y in objects],
            "lat": 48.0,
        }
    )
    q = pd.DataFrame(
        {
            "scene": name,
            "token": [f"{name}-{k}" for k in range(len(views))],
            "split": "train",
            "x_m": [v[0] for v in views],
            "y_m": [v[1] for v in views],
            "theta_deg": [v[2] for v in views],
            "ref_idx": [list(v[3]) for v in views],
        }
    )
    return ref, q


def mirrored_city():
    """Region A (the corner) and region B 1 km east: the same classes seen by a view there, but
    mirrored left to right, so one heading cannot line up B's objects with the corner's bearings."""
    filler = [(4, -15.0, 0.0), (4, 5.0, -20.0)]
    a = [(c, x, y) for c, x, y in CORNER] + filler
    b = [(c, x, -y) for c, x, y in CORNER] + filler
    ref_a, views_a = scene("A", a, [(0.5, 0.3, 2.0, [0, 1, 2, 3])])
    ref_b, views_b = scene("B", b, [(0.5, -0.3, -2.0, [0, 1, 2, 3])])
    return tiling.tile([ref_a, ref_b], [views_a, views_b], 1000.0)


def test_index_finds_the_only_region_that_explains_a_query():
    ref, views = mirrored_city()
    ix = index.build(ref, views)
    q_gt = np.array([[x, y] for _, x, y in CORNER])
    q = q_gt / np.median(np.hypot(*q_gt.T))  # a depth map: bearings kept, median range 1
    q_cls = np.array([c for c, _, _ in CORNER])
    cfg = search.SearchConfig.from_dict({"regions": 1})
    top, score = search.view_scores(ix, q, q_cls, cfg)
    assert ix.cam[top[0], 0] < 500  # the corner's view, though B's saw the same classes
    assert score[0] > score[1] + 0.2  # by its geometry: the bags of classes are equal
    settings = solver.SolverConfig.from_dict({"covis_weight": 0.0})
    found = search.search_city(ix, q, q_cls, cfg, settings, solver.LearnedPriors(scale=(np.log(17.0), 0.5)))
    assert np.hypot(*found.centres[0]) < 50
    assert set(ix.obj_id[found.rows]) == set(range(6))  # region B was never searched
    assert found.solution is not None
    assert np.hypot(found.solution.x, found.solution.y) < 1.0
    assert abs(found.solution.theta) < np.radians(2)


def test_index_round_trips(tmp_path):
    ref, views = mirrored_city()
    ix = index.build(ref, views)
    ix.save(tmp_path / "city.npz")
    back = index.ViewIndex.load(tmp_path / "city.npz")
    for f in ("obj_xy", "obj_cls", "obj_id", "cam", "view_ptr", "view_obj", "idf"):
        np.testing.assert_array_equal(getattr(back, f), getattr(ix, f))
    np.testing.assert_array_equal(back.hist.toarray(), ix.hist.toarray())


def test_tiled_map_keeps_ids_geometry_and_priors():
    ref_a, q_a = scene("A", [(1, 0.0, 0.0), (2, 10.0, 0.0)], [(1.0, -5.0, 90.0, [1, 0])])
    ref_b, q_b = scene("B", [(3, 5.0, 5.0), (1, -5.0, 5.0), (2, 0.0, 20.0)], [(0.0, 0.0, 45.0, [2])])
    for q, ref in ((q_a, ref_a), (q_b, ref_b)):  # each view's GT local map in its own scene
        q["gt_local_xy_m"] = [
            local_map(
                ref.set_index("obj_idx").loc[list(r.ref_idx), ["x_m", "y_m"]], [r.x_m, r.y_m], np.radians(r.theta_deg)
            ).tolist()
            for r in q.itertuples()
        ]
    city, q = tiling.tile([ref_a, ref_b], [q_a, q_b], 1000.0)
    assert list(city["obj_idx"]) == [0, 1, 2, 3, 4]
    assert list(city["scene_obj_idx"]) == [0, 1, 0, 1, 2]
    np.testing.assert_allclose(city.loc[city.scene == "B", ["x_m", "y_m"]], ref_b[["x_m", "y_m"]] + [1000.0, 0.0])
    assert list(q["ref_idx"]) == [[1, 0], [4]]
    by_id = city.set_index("obj_idx")
    for r in q.itertuples():  # the city pose sees the city objects exactly as the scene pose saw its own
        seen = local_map(by_id.loc[r.ref_idx, ["x_m", "y_m"]], [r.x_m, r.y_m], np.radians(r.theta_deg))
        np.testing.assert_allclose(seen, localmaps.xy(r.gt_local_xy_m), atol=1e-9)
    prior, seen_ids = priors.training_priors(q, {"covis_weight": 2.0})
    np.testing.assert_allclose(prior[:, :2], [[1.0, -5.0], [1000.0, 0.0]])
    assert [list(s) for s in seen_ids] == [[1, 0], [4]]


def test_groups_cut_scenes_into_consecutive_cities():
    assert tiling.groups(list("abcde"), 2) == [["a", "b"], ["c", "d"], ["e"]]
    np.testing.assert_allclose(tiling.grid_offsets(5, 10.0), [[0, 0], [10, 0], [20, 0], [0, 10], [10, 10]])


@pytest.mark.parametrize("seed", [0, 1])
def test_synthetic_tile_mirrors_a_scene_without_copying_it(seed):
    objects = [(1, 0.0, 0.0), (2, 30.0, 0.0), (3, 10.0, 20.0), (1, 40.0, 35.0)]
    ref, views = scene("A", objects, [(5.0, -5.0, 30.0, [0, 1, 2])])
    t = simulate.Template(ref, views)
    xy, cam, heading = simulate.synthetic_tile(t, np.random.default_rng(seed), jitter_m=0.0)
    np.testing.assert_allclose(distances(xy), distances(t.xy), atol=1e-9)  # spacing kept
    assert np.sign(signed_area(xy)) == -np.sign(signed_area(t.xy))  # mirrored: no rigid copy of the scene
    # the view sees its objects at the same ranges and at mirrored bearings
    seen = t.seen[0]
    before = local_map(t.xy[seen], t.cam[0], t.heading[0])
    after = local_map(xy[seen], cam[0], heading[0])
    np.testing.assert_allclose(after, before * [1, -1], atol=1e-9)


def test_simulated_city_holds_the_scene_and_enough_objects():
    ref, views = scene("A", CORNER, [(0.0, 0.0, 0.0, [0, 1])])
    t = simulate.Template(ref, views)
    city, q = simulate.city([ref], [views], [t], 50, 1000.0, 1.0, np.random.default_rng(0))
    assert len(city) >= 50 and city["obj_idx"].is_unique
    assert (city["scene"] == "A").sum() == len(ref)
    synthetic = q[q["scene"] != "A"]
    assert (synthetic["split"] == "train").all()
    # every synthetic view saw objects of its own tile, of the template's classes
    for r in synthetic.itertuples():
        tile = city.set_index("obj_idx").loc[r.ref_idx]
        assert (tile["scene"] == r.scene).all()
        assert list(tile["class_id"]) == [1, 2]
