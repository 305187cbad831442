"""Know when it is right (issue "Know when it is right, second pass"): a complete hypothesis set
seeded at every training camera, a null hypothesis, the depth maps' radial bearing distortion, and
the city solved region by region.

Hand-made maps (fast): a scene of random objects with training cameras and a hand-set verifier; a
constellation repeated at two or three places; a synthetic lens; two tiles of a city."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from test_likelihood import flat_model

from flatlandia import config, localize, solver
from flatlandia.city import index, search
from flatlandia.classes import CLASSES
from flatlandia.solver import calibration, calibration_fit, distortion, hypotheses, nonsense, verify
from flatlandia.solver.calibration import Calibration
from flatlandia.solver.noise import NoiseModel

CLASS_IDS = np.array([CLASSES.index(c) for c in CLASSES[1:21]])
#: a hand-set verifier: a pose is likelier right the lower its costs and the better the nearby
#: training cameras' objects agree with its matches (the learned one's signs, docs/results.md)
VERIFIER = verify.Verifier(
    np.array([-1.0, -0.5, -1.0, 2.0, 1.0, 0.0, -0.5, -0.2, 0.0]), np.zeros(len(verify.FEATURES)), np.ones(9)
)
THRESHOLD = config.section_defaults("solver")["answer_probability"]


def world_to_local(xy, pose) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = np.asarray(xy, float) - np.asarray(pose[:2], float)
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def visible(ref_xy, pose, max_range=45.0, fov_deg=50.0) -> np.ndarray:
    loc = world_to_local(ref_xy, pose)
    r, b = np.hypot(*loc.T), np.degrees(np.arctan2(loc[:, 1], loc[:, 0]))
    return np.flatnonzero((r > 2.0) & (r < max_range) & (np.abs(b) < fov_deg))


class Scene:
    """Random objects of six classes over a square, training cameras looking at them, and queries
    seen from other cameras (bearings within 0.5 deg, ranges within a factor of about 1.3)."""

    def __init__(self, seed: int, extent: float = 160.0, n_objects: int = 90, n_cameras: int = 70):
        rng = self.rng = np.random.default_rng(seed)
        self.xy = rng.uniform(0, extent, (n_objects, 2))
        self.cls = rng.choice(CLASS_IDS, n_objects)
        cams = []
        while len(cams) < n_cameras:
            pose = np.r_[rng.uniform(10, extent - 10, 2), rng.uniform(-math.pi, math.pi)]
            if len(visible(self.xy, pose)) >= 4:
                cams.append(pose)
        self.cams = np.array(cams)
        seen = np.zeros((n_cameras, n_objects), bool)
        for k, pose in enumerate(self.cams):
            seen[k, visible(self.xy, pose)] = True
        self.seen = seen

    def priors(self, **kw) -> solver.TrainingPriors:
        return solver.TrainingPriors(
            self.cams, self.seen, (math.log(20.0), 0.5), VERIFIER, flat_model(), kw.get("calibration")
        )

    def query(self, near_camera: int | None = None, most: int = 6):
        """(depth map, classes, true pose) of a camera 1-4 m from a training camera (or anywhere)."""
        rng = self.rng
        while True:
            if near_camera is None:
                base = self.cams[rng.integers(len(self.cams))]
            else:
                base = self.cams[near_camera]
            pose = base + np.r_[rng.uniform(-3, 3, 2), math.radians(rng.uniform(-10, 10))]
            seen = visible(self.xy, pose)
            if len(seen) >= 3:
                break
        seen = seen[np.argsort(np.hypot(*world_to_local(self.xy[seen], pose).T))][:most]
        loc = world_to_local(self.xy[seen], pose)
        r = np.hypot(*loc.T) * np.exp(rng.normal(0, 0.25, len(seen)))
        b = np.arctan2(loc[:, 1], loc[:, 0]) + np.radians(rng.normal(0, 0.5, len(seen)))
        xy = np.column_stack([r * np.cos(b), r * np.sin(b)])
        return xy / np.median(r), self.cls[seen], pose


def error(sol, truth) -> tuple[float, float]:
    turn = abs((sol.theta - truth[2] + math.pi) % (2 * math.pi) - math.pi)
    return math.hypot(sol.x - truth[0], sol.y - truth[1]), math.degrees(turn)


# ---------------------------------------------------------------- a complete set of hypotheses
def test_a_pose_at_a_seed_is_found_when_the_cost_picked_hypotheses_are_all_elsewhere(monkeypatch):
    """The cost-picked search proposes only a wrong place (its generator replaced by one that
    does), 60 m and 90 deg from the truth: without seeds the answer is that place; with a seed at
    every training camera the true pose, 2 m from a camera, is found."""
    scene = Scene(1)
    xy, cls, truth = scene.query(near_camera=5)
    wrong = truth + np.r_[60.0, 0.0, math.pi / 2]

    def elsewhere(problem, priors):
        yield np.tile(wrong[:2], (4, 1)), np.full(4, wrong[2]), np.full(4, 20.0)

    monkeypatch.setattr(hypotheses, "hypothesis_batches", elsewhere)
    cfg = {"prior_radius_m": 200.0}
    without = solver.locate(xy, cls, scene.xy, scene.cls, False, {**cfg, "camera_hypotheses": False}, scene.priors())
    assert without.best is None or error(without.best, truth)[0] > 20.0
    found = solver.locate(xy, cls, scene.xy, scene.cls, False, cfg, scene.priors())
    assert found.best is not None
    e_m, e_deg = error(found.best, truth)
    assert e_m < 2.0 and e_deg < 3.0, (e_m, e_deg)
    assert found.best.n_hypotheses >= len(scene.cams)  # one seed per camera at least


PATTERN = np.array([[12.0, 4.0], [18.0, -5.0], [25.0, 7.0], [30.0, -2.0], [8.0, -9.0]])
PATTERN_CLS = CLASS_IDS[[0, 1, 2, 0, 1]]
VIEW = np.array([1.5, 0.5, math.radians(4.0)])  # the training camera at each copy


def copies(n: int):
    """The constellation at ``n`` places 300 m apart (each turned), a training camera at each
    (seeing its copy), and the query seen from the first place."""
    xy, cls, cams, seen = [], [], [], []
    for k in range(n):
        th = math.radians(35.0 * k)
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        t = np.array([300.0 * k, 0.0])
        xy.append(PATTERN @ rot.T + t)
        cls.append(PATTERN_CLS)
        cams.append(np.r_[rot @ VIEW[:2] + t, VIEW[2] + th])
    ref_xy, ref_cls, cams = np.vstack(xy), np.concatenate(cls), np.array(cams)
    seen = np.zeros((n, len(ref_xy)), bool)
    for k in range(n):
        seen[k, 5 * k : 5 * k + 5] = True
    loc = world_to_local(PATTERN, np.zeros(3))
    q = loc / np.median(np.hypot(*loc.T))
    priors = solver.TrainingPriors(cams, seen, (math.log(15.0), 0.5), VERIFIER, flat_model())
    return q, PATTERN_CLS, ref_xy, ref_cls, priors


@pytest.mark.parametrize("n", [2, 3])
def test_identical_places_share_the_probability(n):
    """Two identical places: `ambiguous` at about 0.5 each; three: about 1/3 each."""
    q, q_cls, ref_xy, ref_cls, priors = copies(n)
    found = solver.locate(q, q_cls, ref_xy, ref_cls, False, None, priors, alternatives=n)
    answers = [found.best, *found.alternatives][:n]
    assert all(a is not None for a in answers)
    places = sorted(round(a.x / 300.0) for a in answers)
    assert places == list(range(n))  # one answer at each copy
    for a in answers:
        assert a.probability == pytest.approx(1.0 / n, abs=0.05)
    assert localize.answer_status(found.best, THRESHOLD)["status"] == "ambiguous"


# ---------------------------------------------------------------- the camera's distortion
def distorted_scene(k: float, seed: int = 0, n: int = 80) -> pd.DataFrame:
    """Training queries whose depth maps' bearings d satisfy b = d + k d^3 against the GT bearings
    b (the inverse found by Newton), with 0.3 deg of noise."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        m = int(rng.integers(3, 8))
        b = np.radians(rng.uniform(-50, 50, m))
        r = rng.uniform(5, 40, m)
        d = b.copy()
        for _ in range(30):
            d -= (d + k * d**3 - b) / (1 + 3 * k * d**2)
        d += np.radians(rng.normal(0, 0.3, m))
        gt = np.column_stack([r * np.cos(b), r * np.sin(b)])
        dep = np.column_stack([np.cos(d), np.sin(d)]) * (r / np.median(r))[:, None]
        rows.append({"token": str(i), "split": "train", "gt_local_xy_m": list(gt), "depth_local_xy": list(dep)})
    return pd.DataFrame(rows)


def test_a_known_radial_distortion_is_recovered_and_none_where_there_is_none():
    ref = pd.DataFrame({"scene": ["lens", "lens"]})
    got = distortion.fit([(ref, distorted_scene(0.2))])
    assert got["lens"] == pytest.approx(0.2, rel=0.1)
    assert distortion.fit([(ref, distorted_scene(0.0, seed=1))]) == {}
    # undone: the corrected bearings are the GT ones within the noise
    q = distorted_scene(0.2, seed=2).iloc[0]
    fixed = distortion.undistort(np.array(list(q["depth_local_xy"])), got["lens"])
    gt = np.array(list(q["gt_local_xy_m"]))
    err = np.degrees(np.arctan2(fixed[:, 1], fixed[:, 0]) - np.arctan2(gt[:, 1], gt[:, 0]))
    assert np.all(np.abs(err) < 2.0)


def test_a_scene_without_a_coefficient_is_solved_unchanged():
    scene = Scene(4)
    xy, cls, _ = scene.query()
    a = solver.locate(xy, cls, scene.xy, scene.cls, False, None, scene.priors()).best
    b = solver.locate(
        xy,
        cls,
        scene.xy,
        scene.cls,
        False,
        None,
        solver.TrainingPriors(**{**scene.priors().__dict__, "bearing_k": 0.0}),
    ).best
    assert (a.x, a.y, a.theta) == (b.x, b.y, b.theta)


# ---------------------------------------------------------------- the null hypothesis
def fitted_scene(seed: int = 2):
    """A scene, its calibration (null key and logistic map) fitted on 60 real queries and as many
    nonsense queries of each kind (the second scene's queries for ``other_scene``)."""
    scene, other = Scene(seed), Scene(seed + 100)
    real = [scene.query() for _ in range(60)] + [scene.query(most=3) for _ in range(20)]
    rows = []
    for xy, cls, truth in real:
        best = solver.locate(xy, cls, scene.xy, scene.cls, False, None, scene.priors()).best
        right = best is not None and max(np.array(error(best, truth)) / 5.0) < 1.0
        rows.append(_row("", cls, best, right))
    queries = [[(xy, cls) for xy, cls, _ in real], [other.query()[:2] for _ in range(40)]]
    for n in nonsense.draw(queries, [scene.cls, other.cls], seed):
        if n.scene != 0:
            continue
        best = solver.locate(n.xy, n.classes, scene.xy, scene.cls, False, None, scene.priors()).best
        rows.append(_row(n.kind, n.classes, best, False))
    evidence = pd.DataFrame(rows)
    null_key, frame = calibration_fit.fit_null(evidence)
    return scene, evidence, null_key, frame


def _row(kind, cls, best, right):
    return {
        "nonsense": kind,
        "objects": len(cls),
        "log_place": -np.inf if best is None else best.log_place,
        "log_pool": -np.inf if best is None else best.log_pool,
        "right": bool(right),
    }


def test_random_layouts_are_never_ok():
    """With the null hypothesis fitted on real and nonsense queries of the scene, 100 fresh random
    layouts (the map's classes at random places in view) get no `ok`, while real queries do."""
    scene, evidence, null_key, frame = fitted_scene()
    assert null_key is not None and frame is not None
    priors = scene.priors(calibration=Calibration(frame=frame, null_key=null_key))
    rng = np.random.default_rng(99)
    statuses = []
    for _ in range(100):
        m = int(rng.integers(3, 7))
        xy, cls = nonsense.random_layout(rng, m), rng.choice(scene.cls, m)
        best = solver.locate(xy, cls, scene.xy, scene.cls, False, None, priors).best
        statuses.append("no pose" if best is None else localize.answer_status(best, THRESHOLD)["status"])
    assert "ok" not in statuses
    real = [scene.query() for _ in range(30)]
    ok = [
        localize.answer_status(b, THRESHOLD)["status"] == "ok"
        for b in (solver.locate(xy, cls, scene.xy, scene.cls, False, None, priors).best for xy, cls, _ in real)
        if b is not None
    ]
    assert sum(ok) >= 10


def test_the_null_hypothesis_lowers_only_weak_pools():
    """A pool whose evidence far exceeds the null's keeps its share; one far below loses it; no
    null key changes nothing."""
    share = calibration.null_share(np.array([10.0, 0.0]), np.array([10.0, 0.0]), null_key=-5.0)
    assert share[0] > 0.99 and share[1] < 0.01  # a strong pool keeps its share, a weak one loses it
    assert np.allclose(calibration.null_share(np.array([0.0, -1.0]), 0.0), [1.0, math.exp(-1.0)])


# ---------------------------------------------------------------- the city, region by region
def tiles(identical: bool):
    """A city of two tiles 2 km apart: the scene and a copy of it (or another random scene)."""
    a = Scene(7)
    b = a if identical else Scene(8)
    shift = np.array([2000.0, 0.0])
    ref = pd.DataFrame(
        {
            "obj_idx": np.arange(len(a.xy) + len(b.xy)),
            "class_id": np.r_[a.cls, b.cls],
            "x_m": np.r_[a.xy[:, 0], b.xy[:, 0] + shift[0]],
            "y_m": np.r_[a.xy[:, 1], b.xy[:, 1]],
        }
    )
    cams = np.vstack([a.cams, b.cams + np.r_[shift, 0.0]])
    seen = [np.flatnonzero(s) for s in a.seen] + [np.flatnonzero(s) + len(a.xy) for s in b.seen]
    views = pd.DataFrame(
        {
            "token": [str(k) for k in range(len(cams))],
            "x_m": cams[:, 0],
            "y_m": cams[:, 1],
            "theta_deg": np.degrees(cams[:, 2]),
            "ref_idx": [list(s) for s in seen],
        }
    )
    return a, index.build(ref, views)


@pytest.mark.parametrize("identical", [True, False])
def test_the_city_by_region_is_ambiguous_between_identical_tiles_and_sure_between_distinct(identical):
    scene, ix = tiles(identical)
    cfg = search.SearchConfig.from_dict({"regions": 2, "nms_m": 1000.0, "region_radius_m": 150.0})
    settings = solver.SolverConfig.from_dict({})
    learned = solver.LearnedPriors(scale=(math.log(20.0), 0.5), verifier=VERIFIER, likelihood=flat_model())
    statuses = []
    for seed in range(4):
        xy, cls, truth = Scene(7).query(near_camera=10 + seed)
        found = search.search_city(ix, xy, cls, cfg, settings, learned, False, 2)
        assert found.solution is not None
        in_tile = min(error(found.solution, truth)[0], error(found.solution, truth + np.r_[2000.0, 0, 0])[0])
        assert in_tile < 5.0
        statuses.append(localize.answer_status(found.solution, THRESHOLD)["status"])
        if identical:
            assert found.solution.probability == pytest.approx(0.5, abs=0.1)
    assert set(statuses) == ({"ambiguous"} if identical else {"ok"})


def test_the_localizer_applies_its_scenes_bearing_correction():
    """`flatlandia localize` builds a scene map's priors from the map's scene id, so its depth maps
    get the same bearing correction as rule fine_eval's; a map of another scene gets none."""
    from flatlandia.localize import maps

    queries = pd.DataFrame({"split": ["train"], "x_m": [0.0], "y_m": [0.0], "theta_deg": [0.0], "ref_idx": [[1, 2]]})
    lens = dataclasses.replace(NoiseModel.constant(1.0, 0.5), distortion={"0": 0.2})
    learned = solver.LearnedPriors(scale=(2.0, 0.5), noise=lens)
    on = solver.scene_priors(maps.pd_frame([1, 2, 3], "0"), queries, None, learned)
    off = solver.scene_priors(maps.pd_frame([1, 2, 3], "7"), queries, None, learned)
    assert on.bearing_k == pytest.approx(0.2) and off.bearing_k == 0.0
    assert solver.scene_priors(maps.pd_frame([1, 2, 3]), queries, None, learned).bearing_k == 0.0
