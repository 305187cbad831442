"""The likelihood ratio against chance, its fit and the answers' calibration (issue "Know when it is
right"), on hand-made maps and synthetic scenes (fast: no published data).

- a pose that should see one more map object in view than it detected scores lower than the same
  pose without that object (negative evidence);
- three detections explained by objects of a class dense around them score lower than the same
  three explained by a rare class, at the same residuals (the chance term);
- the noise model, the field of view and p_d fitted on a synthetic scene of known values recover
  them;
- the calibration fitted on one synthetic benchmark is calibrated on another (ECE within 5 points);
- the learned priors carry the model and the calibration through JSON, and a corrupt file is one
  clear error; a bad ``solver.answer_probability`` is one ERROR line at config parse.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from flatlandia import classes, config, geo
from flatlandia.classes import CLASSES
from flatlandia.plumbing.errors import InputError
from flatlandia.solver import calibration, learned_priors, likelihood, noise
from flatlandia.solver.likelihood import BEARING_EDGES_DEG, LikelihoodModel
from flatlandia.solver.noise import RANGE_EDGES_M, NoiseModel
from flatlandia.solver.priors import Priors, TrainingPriors
from flatlandia.solver.problem import Problem
from flatlandia.solver.settings import SolverConfig

LIGHT, HYDRANT, BENCH = (CLASSES.index(c) for c in ("object--street-light", "object--fire-hydrant", "object--bench"))


#: one noise for every range: what the hand-made maps below are scored with
FLAT_NOISE = NoiseModel.constant(1.0, 0.3)


def flat_model(p_d: float = 0.3, fov_deg: float = 50.0) -> LikelihoodModel:
    """A model with one detection probability for every class, range and bearing."""
    nb, na, nk = len(RANGE_EDGES_M) - 1, len(BEARING_EDGES_DEG) - 1, classes.N_CLASSES
    z = math.log(p_d / (1 - p_d))
    zeros = (0.0,) * nk, (0.0,) * nb, (0.0,) * na
    return LikelihoodModel(fov_deg, 80.0, z, *zeros, 0.0, 0.0, z, *zeros)


def local(xy, pose) -> np.ndarray:
    return geo.world_to_local(np.asarray(xy, float), np.asarray(pose[:2], float), float(pose[2]))


def depth_map(xy, pose) -> tuple[np.ndarray, float]:
    """The depth map of map points seen from ``pose`` (bearings exact, median range 1) and its scale."""
    loc = local(xy, pose)
    scale = float(np.median(np.hypot(*loc.T)))
    return loc / scale, scale


def llr_at(pose, q_xy, q_cls, ref_xy, ref_cls, scale, model=None, radius=25.0) -> tuple[float, np.ndarray]:
    """The likelihood ratio of one pose of a depth query on a map, and its parts."""
    cfg = SolverConfig.from_dict({})
    problem = Problem(q_xy, q_cls, ref_xy, ref_cls, False, cfg, FLAT_NOISE)
    priors = Priors(cfg, False, TrainingPriors(), n_ref=len(problem.r))
    llr, _, parts = likelihood.pose_llr(
        problem, priors, model or flat_model(), radius, np.asarray([pose[:2]]), [pose[2]], [scale]
    )
    return float(llr[0]), parts[0]


POSE = np.array([0.0, 0.0, 0.0])
SEEN = np.array([[12.0, 4.0], [18.0, -5.0], [25.0, 7.0], [30.0, -2.0]])
SEEN_CLS = np.array([LIGHT, LIGHT, BENCH, HYDRANT])


def test_an_object_in_view_that_was_not_detected_costs():
    q, scale = depth_map(SEEN, POSE)
    base, parts = llr_at(POSE, q, SEEN_CLS, SEEN, SEEN_CLS, scale)
    extra_xy = np.vstack([SEEN, [[20.0, 1.0]]])  # in front, in range: the camera should have seen it
    more, more_parts = llr_at(POSE, q, SEEN_CLS, extra_xy, np.r_[SEEN_CLS, BENCH], scale)
    assert more < base - 0.3  # log(1 - 0.3) = -0.36 for the missed bench
    assert more_parts[1] == pytest.approx(parts[1] + math.log(1 - 0.3), abs=1e-6)
    behind_xy = np.vstack([SEEN, [[-20.0, 1.0]]])  # behind the camera: it could not have seen it
    behind, _ = llr_at(POSE, q, SEEN_CLS, behind_xy, np.r_[SEEN_CLS, BENCH], scale)
    assert behind == pytest.approx(base, abs=1e-9)
    far_xy = np.vstack([SEEN, [[200.0, 1.0]]])  # beyond the fitted range
    far, _ = llr_at(POSE, q, SEEN_CLS, far_xy, np.r_[SEEN_CLS, BENCH], scale)
    assert far == pytest.approx(base, abs=1e-9)


def test_three_trees_in_a_row_of_trees_count_for_less_than_three_rare_objects():
    """The same three detections at the same residuals (exact), explained by street lights in a row of
    street lights or by fire hydrants alone; the rest of the row stands behind the camera in both
    maps (out of view: no missed object), as lights or as benches."""
    three = np.array([[10.0, 3.0], [16.0, -4.0], [22.0, 5.0]])
    row = np.column_stack([np.linspace(-12.0, -1.0, 15), np.linspace(-6.0, 6.0, 15)])
    q, scale = depth_map(three, POSE)
    ref_xy = np.vstack([three, row])
    lights, lp = llr_at(POSE, q, [LIGHT] * 3, ref_xy, [LIGHT] * 18, scale)
    hydrants, hp = llr_at(POSE, q, [HYDRANT] * 3, ref_xy, [HYDRANT] * 3 + [BENCH] * 15, scale)
    # each light is one of n lights within 25 m, each hydrant one of the three: the chance of a light
    # lying there is n / 3 times higher
    n = [int((np.hypot(*(ref_xy - p).T) <= 25.0).sum()) for p in three]
    assert min(n) >= 5
    assert hydrants - lights == pytest.approx(sum(math.log(k / 3) for k in n), abs=1e-9)
    assert hydrants - lights > 3.0
    assert lp[1] == pytest.approx(3 * math.log(1 - 0.3)) == hp[1]  # in view: the three alone, in both maps
    assert lp[2] == pytest.approx(hp[2]) and lp[3] == pytest.approx(hp[3])  # the same residuals


# ----------------------------------------------------------------------------- the fit recovers known values

TRUE_BEARING_DEG, TRUE_LOG_RANGE, TRUE_FOV_DEG, TRUE_RANGE_M = 0.8, 0.25, 45.0, 70.0
#: a detection probability per class: the fit must tell them apart
TRUE_P_D = {LIGHT: 0.5, BENCH: 0.2, HYDRANT: 0.05}


def synthetic_scene(seed: int = 0, n_objects: int = 600, n_queries: int = 700) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A scene of known noise and detection probability in the published tables' shape: objects of
    three classes over 300 x 300 m; training cameras anywhere, each detecting every object in its
    field of view (half-angle ``TRUE_FOV_DEG``, range ``TRUE_RANGE_M``) with its class's p_d; the
    depth map: bearings with Gaussian noise ``TRUE_BEARING_DEG``, log ranges ``TRUE_LOG_RANGE``,
    an arbitrary scale."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-150, 150, (n_objects, 2))
    cls = rng.choice(list(TRUE_P_D), n_objects)
    ref = pd.DataFrame({"obj_idx": np.arange(n_objects), "class_id": cls, "x_m": xy[:, 0], "y_m": xy[:, 1]})
    rows = []
    while len(rows) < n_queries:
        pose = np.r_[rng.uniform(-120, 120, 2), rng.uniform(-np.pi, np.pi)]
        loc = local(xy, pose)
        rr, bb = np.hypot(*loc.T), np.degrees(np.abs(np.arctan2(loc[:, 1], loc[:, 0])))
        view = (loc[:, 0] > 0) & (bb <= TRUE_FOV_DEG) & (rr <= TRUE_RANGE_M)
        det = np.flatnonzero(view & (rng.random(n_objects) < np.vectorize(TRUE_P_D.get)(cls)))
        if len(det) < 3:
            continue
        g = loc[det]
        b = np.arctan2(g[:, 1], g[:, 0]) + np.radians(TRUE_BEARING_DEG) * rng.standard_normal(len(det))
        r = np.hypot(*g.T) * np.exp(TRUE_LOG_RANGE * rng.standard_normal(len(det))) / 37.0
        rows.append(
            {
                "token": f"q{len(rows)}",
                "split": "train",
                "x_m": pose[0],
                "y_m": pose[1],
                "theta_deg": math.degrees(pose[2]),
                "ref_idx": det.tolist(),
                "classes": cls[det].tolist(),
                "n_objects": len(det),
                "gt_local_xy_m": g.tolist(),
                "depth_local_xy": np.column_stack([r * np.cos(b), r * np.sin(b)]).tolist(),
            }
        )
    return ref, pd.DataFrame(rows)


@pytest.fixture(scope="module")
def fitted() -> LikelihoodModel:
    return likelihood.fit([synthetic_scene()])


def test_the_noise_model_recovers_the_known_sigmas():
    model = noise.fit([synthetic_scene()], bearing_correction=False)
    edges = np.asarray(RANGE_EDGES_M)
    for k in range(len(edges) - 1):
        if edges[k] >= 5 and edges[k + 1] <= TRUE_RANGE_M:  # bins with enough detections
            assert model.bearing_sigma_deg[k] == pytest.approx(TRUE_BEARING_DEG, rel=0.15), k
            assert model.log_range_sigma[k] == pytest.approx(TRUE_LOG_RANGE, rel=0.15), k


def test_the_field_of_view_and_range_come_from_the_detections(fitted):
    assert 0.95 * TRUE_FOV_DEG <= fitted.fov_half_deg <= TRUE_FOV_DEG + 0.5
    assert 0.9 * TRUE_RANGE_M <= fitted.max_range_m <= TRUE_RANGE_M + 0.5


def test_the_detection_probability_recovers_each_class(fitted):
    """p_d0 (without views) at a typical range and bearing, per class, within 0.06 of the truth."""
    t = fitted.terms(False, 0.25, FLAT_NOISE)
    from flatlandia.solver.likelihood_kernels import _detection

    for k, p in TRUE_P_D.items():
        got = np.mean(
            [_detection.py_func(t, k, r, math.radians(b), 0.0, 1.0)[1] for r in (15, 30, 50) for b in (5, 25, 40)]
        )
        assert got == pytest.approx(p, abs=0.06), (CLASSES[k], got)


# ----------------------------------------------------------------------------- the calibration


def synthetic_answers(rng, n: int) -> pd.DataFrame:
    """Answers whose pool share is overconfident in a known way: P(right) = sigmoid(0.4 logit(share)
    - 0.5 + 0.6 log(objects / 4))."""
    share = 1 / (1 + np.exp(-rng.normal(2.0, 4.0, n)))
    objects = rng.integers(3, 12, n)
    z = 0.4 * np.log(share / (1 - share)) - 0.5 + 0.6 * np.log(objects / 4)
    right = rng.random(n) < 1 / (1 + np.exp(-z))
    return pd.DataFrame({"frames": 1, "objects": objects, "pool_share": share, "agreement": 1.0, "right": right})


def test_the_calibration_is_calibrated_on_another_draw():
    rng = np.random.default_rng(3)
    val, test = synthetic_answers(rng, 3000), synthetic_answers(rng, 3000)
    cal = learned_priors.with_calibration(learned_priors.LearnedPriors(), val).calibration
    assert cal.frame is not None and cal.sequence is None  # no sequence answers: none fitted
    p = cal.probability(test["pool_share"], test["objects"], 1)
    raw = calibration.expected_calibration_error(test["pool_share"], test["right"])
    ece = calibration.expected_calibration_error(p, test["right"])
    assert ece <= 5.0 < raw, (ece, raw)
    assert cal.frame.weights[0] == pytest.approx(0.4, abs=0.1)


def test_risk_coverage_and_the_largest_share_answerable():
    p = np.array([0.9, 0.8, 0.7, 0.6, 0.5])
    bad = np.array([False, False, True, False, True])
    cov, risk = calibration.risk_coverage(p, bad)
    assert cov.tolist() == [20, 40, 60, 80, 100] and risk[2] == pytest.approx(100 / 3)
    assert calibration.largest_coverage(p, bad, 0.0) == 40.0
    assert calibration.largest_coverage(p, bad, 30.0) == 80.0
    assert calibration.largest_coverage(p[::-1], bad[::-1], 0.0) == 40.0  # answered surest first


def test_pool_shares_merge_poses_of_one_place():
    t = np.array([[0.0, 0.0], [1.0, 0.0], [100.0, 0.0]])
    share = calibration.pose_masses(t, np.zeros(3), np.array([0.0, 0.0, 0.0]))
    assert share == pytest.approx([2 / 3, 2 / 3, 1 / 3])
    share = calibration.pose_masses(t, np.zeros(3), np.array([0.0, 0.0, 0.0]), ok=[True, False, True])
    assert share == pytest.approx([0.5, 0.0, 0.5])


# ----------------------------------------------------------------------------- stored and checked


def test_the_learned_priors_carry_the_model_and_the_calibration(tmp_path, fitted):
    rng = np.random.default_rng(0)
    model = NoiseModel((2.0, 1.5, 1.2, 1.0, 0.6, 0.5, 0.5), (0.5, 0.4, 0.3, 0.3, 0.4, 0.5, 0.8), {"3": 0.2}, 99)
    lp = learned_priors.with_calibration(
        learned_priors.LearnedPriors((2.0, 0.5), None, fitted, noise=model), synthetic_answers(rng, 500)
    )
    path = tmp_path / "whole.json"
    lp.write(path)
    back = learned_priors.LearnedPriors.read(path)
    assert back.likelihood == fitted and back.calibration == lp.calibration and back.noise == model
    assert back.bearing_k(3) == 0.2 and back.bearing_k(4) == 0.0
    doc = json.loads(path.read_text())
    doc["noise"]["bearing_sigma_deg"][0] = -1.0
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="noise bearing_sigma_deg"):
        learned_priors.LearnedPriors.read(path)
    doc["noise"]["bearing_sigma_deg"][0] = 1.0
    doc["calibration"]["frame"]["weights"] = [1.0]
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="calibration needs 4 finite weights"):
        learned_priors.LearnedPriors.read(path)


@pytest.mark.parametrize("value", [float("nan"), -0.1, 1.5])
def test_a_bad_answer_threshold_is_refused_at_config_parse(value):
    with pytest.raises(config.ConfigError, match="solver.answer_probability"):
        config.resolve({"solver": {"answer_probability": value}})


def test_a_bad_answer_threshold_is_one_error_line(tmp_path):
    from conftest import smk_dry_run

    repo = __import__("pathlib").Path(__file__).resolve().parents[1]
    res = smk_dry_run(
        repo,
        tmp_path,
        "all",
        "--configfile",
        str(repo / "config/test/tiny.yaml"),
        "--config",
        "solver={answer_probability: 1.5}",
    )
    assert res.returncode != 0
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("ERROR:")]
    assert len(errors) == 1 and "'solver.answer_probability': 1.5 is greater than the maximum of 1" in errors[0], errors
    assert "Traceback" not in res.stderr
