"""The solver's co-visibility gate, its learned verifier and the true-match bound: hand-made maps
(a case only the verifier resolves) and real scenes built from the published data."""

import itertools
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from conftest import published_scene

from flatlandia import geo, proposals, solver
from flatlandia.benchmark import solver_runs
from flatlandia.data import localmaps
from flatlandia.solver import bound, kernels, priors, scoring, verify, verify_fit


def _scene(flat_root, scene: str):
    return published_scene(flat_root, scene)


@pytest.fixture(scope="module")
def real_scenes(flat_root):
    """Scenes 8 and 17: about 100 objects and 100 training queries each."""
    return [_scene(flat_root, s) for s in ("8", "17")]


# ----------------------------------------------------------------------------- co-visibility gate


def test_coseen_pairs_and_gated_triples_equal_brute_force():
    rng = np.random.default_rng(0)
    seen = rng.random((30, 40)) < 0.1
    co = priors.coseen(seen)
    np.testing.assert_array_equal(co.pair, (seen.T.astype(int) @ seen.astype(int)) > 0)
    for a in range(40):  # the lists hold each row of the matrix
        np.testing.assert_array_equal(co.idx[co.ptr[a] : co.ptr[a + 1]], np.flatnonzero(co.pair[a]))
    ca, cb, cc = (np.sort(rng.choice(40, 12, replace=False)).astype(np.int64) for _ in range(3))
    distinct = [t for t in itertools.product(ca, cb, cc) if len(set(t)) == 3]
    gated = [t for t in distinct if co.pair[t[0], t[1]] and co.pair[t[0], t[2]] and co.pair[t[1], t[2]]]
    got = kernels._candidate_triples(ca, cb, cc, co, True)
    assert sorted(map(tuple, got.tolist())) == sorted(gated) and 0 < len(gated) < len(distinct)
    got = kernels._candidate_triples(ca, cb, cc, co, False)
    assert sorted(map(tuple, got.tolist())) == sorted(distinct)


def _street(rng, n_ref=300, n_cls=3):
    """Many objects of few classes (a whole map), a camera and its depth map of 5 objects."""
    ref = rng.uniform(-150, 150, (n_ref, 2))
    cls = rng.integers(0, n_cls, n_ref)
    cam, theta = np.array([3.0, -4.0]), 0.7
    local = geo.world_to_local(ref, cam, theta)
    vis = np.flatnonzero((local[:, 0] > 3) & (local[:, 0] < 40) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) < 0.8))
    vis = vis[:5]
    depth = local[vis] / np.median(np.linalg.norm(local[vis], axis=1))
    return ref, cls, cam, theta, depth, cls[vis], vis


def test_covis_gate_keeps_the_true_pose_with_far_fewer_hypotheses():
    """A training camera beside the query saw its objects: hypotheses from co-seen candidates only
    find the same exact pose from a fraction of the hypotheses (under a fifth here)."""
    ref, cls, cam, theta, depth, qc, vis = _street(np.random.default_rng(1))
    prior = np.array([[cam[0], cam[1], theta], [-100.0, 100.0, 0.0], [100.0, -100.0, 2.0]])
    seen = np.zeros((3, len(ref)), bool)
    seen[0, vis] = True
    seen[1:, np.random.default_rng(2).choice(len(ref), 40, replace=False)] = True
    out = {}
    for gate in (0, 10**9):
        cfg = {"covis_gate_above": gate}
        out[gate] = solver.solve(depth, qc, ref, cls, config=cfg, priors=solver.TrainingPriors(prior, seen))
    for s in out.values():
        assert np.hypot(s.x - cam[0], s.y - cam[1]) < 1e-3 and abs(geo.wrap_angle(s.theta - theta)) < 1e-4
    assert out[0].n_hypotheses * 5 < out[10**9].n_hypotheses


# ----------------------------------------------------------------------------- verifier


def _two_copies():
    """Two copies of a street scene 200 m apart with a training camera in front of each; the
    second copy is shifted by centimetres (so the MSAC cost prefers the first), and the camera at
    the first also saw ten objects that the query does not show (so the first is the worse place
    for a camera that saw only these six)."""
    rng = np.random.default_rng(3)
    pattern = np.column_stack([rng.uniform(8, 40, 6), rng.uniform(-15, 15, 6)])
    cls = np.array([0, 1, 2, 0, 1, 2])
    extra = np.column_stack([rng.uniform(-30, -5, 10), rng.uniform(-20, 20, 10)])  # behind the camera
    ref = np.vstack([pattern, extra, pattern + [200.0, 0.0] + rng.normal(0, 0.05, (6, 2))])
    ref_cls = np.concatenate([cls, np.full(10, 5), cls])
    depth = pattern / np.median(np.linalg.norm(pattern, axis=1))  # camera at the second copy's origin
    prior = np.array([[0.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    seen = np.zeros((2, len(ref)), bool)
    seen[0, :16] = True
    seen[1, 16:] = True
    return depth, cls, ref, ref_cls, prior, seen


def test_only_the_verifier_picks_the_place_whose_camera_saw_just_these_objects():
    depth, cls, ref, ref_cls, prior, seen = _two_copies()
    given = solver.TrainingPriors(prior, seen)
    cheapest = solver.solve(depth, cls, ref, ref_cls, priors=given)
    assert np.hypot(cheapest.x, cheapest.y) < 0.5  # the exact copy costs less
    jaccard = np.eye(len(verify.FEATURES))[verify.FEATURES.index("jaccard")]
    verifier = verify.Verifier(jaccard, np.zeros_like(jaccard), np.ones_like(jaccard))
    verified = solver.solve(depth, cls, ref, ref_cls, priors=replace(given, verifier=verifier))
    assert np.hypot(verified.x - 200.0, verified.y) < 0.5 and abs(geo.wrap_angle(verified.theta)) < 0.01
    assert sorted(m for _, m in verified.inliers) == list(range(16, 22))
    # the features say why: a full overlap with the camera there, ten objects seen but not matched here
    pool = solver.candidates(depth, cls, ref, ref_cls, priors=given, use_verifier=True)
    data, _, inl, match = scoring.score_terms(pool.problem, pool.priors, pool.t, pool.theta, pool.s)
    f = verify.features(pool.problem, pool.priors, pool.t, pool.theta, pool.s, data, inl, match)
    assert f.shape == (len(pool.t), len(verify.FEATURES)) and np.isfinite(f).all()
    at = [np.argmin(np.hypot(pool.t[:, 0] - x, pool.t[:, 1])) for x in (0.0, 200.0)]
    col = {name: f[at, k] for k, name in enumerate(verify.FEATURES)}
    assert col["jaccard"] == pytest.approx([6 / 16, 1.0]) and col["uncovered"].tolist() == [0, 0]
    assert col["unseen"][0] > col["unseen"][1] + 5


def test_verifier_fit_learns_the_deciding_feature_deterministically():
    rng = np.random.default_rng(4)
    f_count = len(verify.FEATURES)

    def groups(n):
        out = []
        for _ in range(n):
            f = rng.normal(size=(8, f_count))
            right = np.zeros(8, bool)
            right[np.argmax(f[:, 3] + 0.3 * rng.normal(size=8))] = True  # feature 3 mostly decides
            out.append((f, right))
        return out

    train, held_out = groups(200), groups(100)
    v = verify.fit(train)
    assert np.argmax(np.abs(v.weights)) == 3 and v.weights[3] > 0
    picked = np.mean([right[np.argmax(v.score(f))] for f, right in held_out])
    assert picked > 0.6  # 1 in 8 by chance
    np.testing.assert_array_equal(verify.fit(train).weights, v.weights)
    with pytest.raises(ValueError, match="right hypothesis"):
        verify.fit([(f, np.zeros(len(f), bool)) for f, _ in held_out])


def _within(errors: pd.DataFrame) -> int:
    return int(((errors["error_m"] < 5) & (errors["error_deg"] < 5)).sum())


@pytest.mark.slow  # the published data (flat_root)
def test_verifier_learned_on_real_training_splits_places_more_test_queries(real_scenes):
    """Scenes 8 and 17 on the whole map, depth maps: a verifier learned from their training splits
    (leave-one-out) places more of their val and test queries within (5 m, 5 deg) than the
    cheapest hypothesis does."""
    scale_prior = solver.depth_scale_prior([q for _, q in real_scenes])
    verifier = verify_fit.fit_verifier(real_scenes, {}, scale_prior)
    assert verifier.weights[verify.FEATURES.index("jaccard")] > 0
    counts = {False: 0, True: 0}
    n = 0
    for ref, q in real_scenes:
        held = q[q["split"] != "train"]
        props = proposals.whole_map_proposals(ref, held)
        for use in counts:
            learned = solver.LearnedPriors(scale_prior, verifier if use else None)
            e = solver_runs.evaluate_solver(ref, held, props, "depth", priors=solver.scene_priors(ref, q, {}, learned))
            counts[use] += _within(e)
        n += len(held)
    assert counts[True] > counts[False] and counts[True] >= 0.6 * n


# ----------------------------------------------------------------------------- true-match bound


def test_true_match_bound_is_exact_on_exact_bearings():
    """Exact bearings, ranges off by up to 2x: from a start metres away, bearings alone return the
    pose; with the ranges they pull it by centimetres at most."""
    rng = np.random.default_rng(5)
    cam, theta = np.array([10.0, -5.0]), 0.4
    world = cam + rng.uniform(5, 40, (5, 2)) * [1, 0.5]
    local = geo.world_to_local(world, cam, theta)
    depth = local * np.exp(rng.uniform(-0.7, 0.7, (5, 1))) / 30.0
    start = (cam[0] + 2.0, cam[1] - 1.5, theta + 0.05, 25.0)
    x, y, th = bound.true_match_pose(depth, world, start, ranges=False)
    assert np.hypot(x - cam[0], y - cam[1]) < 1e-6 and abs(geo.wrap_angle(th - theta)) < 1e-8
    x, y, th = bound.true_match_pose(depth, world, start, ranges=True)
    assert np.hypot(x - cam[0], y - cam[1]) < 0.5


@pytest.mark.slow  # the published data (flat_root)
def test_true_match_bound_on_real_scenes_and_priors_tighten_it(real_scenes):
    """Scenes 8 and 17, val and test queries: the bound is metres, not tens of metres, and the
    training-split priors (cameras and scale) bring more queries within 3 m."""
    scale_prior = solver.depth_scale_prior([q for _, q in real_scenes])
    err = {False: [], True: []}
    for ref, q in real_scenes:
        ref_xy = ref[["x_m", "y_m"]].to_numpy()
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"])}
        given = solver.TrainingPriors(solver.priors.training_priors(q)[0], None, scale_prior)
        for r in q[q["split"] != "train"].itertuples(index=False):
            theta = np.radians(r.theta_deg)
            start = (r.x_m, r.y_m, theta, r.depth_oracle_scale_m)
            matched = ref_xy[[pos[int(o)] for o in r.ref_idx]]
            for use in err:
                x, y, _ = bound.true_match_pose(
                    localmaps.local_map(r, "depth"),
                    matched,
                    start,
                    True,
                    given=given if use else None,
                )
                err[use].append(np.hypot(x - r.x_m, y - r.y_m))
    assert np.median(err[False]) < 3.0
    assert np.mean(np.array(err[True]) < 3) > np.mean(np.array(err[False]) < 3)


@pytest.mark.slow  # the published data (flat_root)
def test_no_verifier_without_co_visibility_sets(real_scenes):
    """Without co-visibility (``covis_weight`` 0 leaves the training sets out) there is nothing to
    learn from: no verifier, and the solver keeps the cheapest hypothesis."""
    ref, q = real_scenes[0]
    assert verify_fit.fit_verifier([(ref, q)], {"covis_weight": 0.0}, None) is None
