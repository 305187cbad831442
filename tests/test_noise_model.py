"""The solver's one noise model (flatlandia.solver.noise): the MSAC cost, the refinement, the sequences
and the likelihood read the same sigmas per range bin and the same bearing error (the wrapped angle);
an old priors file is one error naming its format and the rule that rewrites it.

Hand-made maps; no published data.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from flatlandia import config, solver
from flatlandia.plumbing.errors import InputError
from flatlandia.solver import learned_priors, likelihood, noise, scoring
from flatlandia.solver.noise import RANGE_EDGES_M, NoiseModel
from flatlandia.solver.priors import Priors, TrainingPriors
from flatlandia.solver.problem import Problem
from flatlandia.solver.settings import SolverConfig

#: sharp far away, loose near the camera, as the published depth maps are
BINNED = NoiseModel((3.0, 2.0, 1.5, 1.0, 0.6, 0.5, 0.5), (0.6, 0.5, 0.35, 0.3, 0.4, 0.55, 0.9))


def one_object(bearing_error_deg: float, range_m: float, noise_model, tau: float = 3.0):
    """(inlier, cost) of one depth query object seen straight ahead whose only candidate lies at
    ``range_m`` and ``bearing_error_deg`` off the query's bearing, at the true scale."""
    cfg = SolverConfig.from_dict({"tau": tau})
    b = math.radians(bearing_error_deg)
    ref = np.array([[range_m * math.cos(b), range_m * math.sin(b)], [500.0, 500.0]])
    q = np.array([[1.0, 0.0], [5.0, 5.0]])
    pb = Problem(q, [0, 1], ref, [0, 2], False, cfg, noise_model)
    cost, inl, _ = scoring.data_cost(pb, np.zeros((1, 2)), np.zeros(1), np.array([range_m]))
    return bool(inl[0, 0]), float(cost[0]) - float(tau**2)  # object 1 has no candidate: capped


@pytest.mark.parametrize(("range_m", "sigma_deg"), [(3.0, 3.0), (15.0, 1.5), (45.0, 0.6), (80.0, 0.5)])
def test_the_msac_inlier_test_follows_the_sigma_of_the_candidates_range(range_m, sigma_deg):
    """An object 2.9 sigmas off is an inlier and 3.1 sigmas off is not, whatever its range bin's sigma."""
    assert one_object(2.9 * sigma_deg, range_m, BINNED)[0]
    assert not one_object(3.1 * sigma_deg, range_m, BINNED)[0]
    inl, cost = one_object(2.0 * sigma_deg, range_m, BINNED)
    assert inl and cost == pytest.approx(4.0, rel=1e-6)  # the range is exact: the bearing's 2 sigmas alone


def test_the_msac_bearing_error_is_the_wrapped_angle_not_its_tangent():
    """At 60 degrees off (tau wide enough to keep it) the cost is (60 / sigma)^2; the tangent would give
    (tan 60 / sigma)^2, three times as much."""
    model = NoiseModel.constant(10.0, 0.5)
    inl, cost = one_object(60.0, 20.0, model, tau=100.0)
    assert inl and cost == pytest.approx(36.0, rel=1e-6)


def test_the_kernels_match_the_numpy_reference_with_a_binned_model():
    rng = np.random.default_rng(0)
    ref, cls = rng.uniform(-100, 100, (150, 2)), rng.integers(0, 6, 150)
    q, qc = rng.uniform(1, 30, (7, 2)), rng.integers(0, 6, 7)
    pb = Problem(q, qc, ref, cls, False, SolverConfig.from_dict({"tau": 6.0}), BINNED)
    t, th, s = rng.uniform(-100, 100, (3000, 2)), rng.uniform(-np.pi, np.pi, 3000), rng.uniform(2, 50, 3000)
    total, inl, _ = scoring.data_cost(pb, t, th, s)
    cost = scoring.padded_costs(pb, t, th, s)
    bc = cost.min(2)
    np.testing.assert_allclose(total, np.minimum(bc, 36.0).sum(1), rtol=1e-4, atol=1e-4)
    ok = np.abs(bc - 36.0) > 1e-3
    assert (inl == (bc < 36.0))[ok].all() and inl.sum() > 100


def test_the_likelihood_reads_the_problems_noise_model():
    """The same pose scored with a looser model explains a detection 2 degrees off better: the ratio's
    bearing term is the model's, not a copy of its own."""
    xy = np.array([[20.0, 1.0], [25.0, -6.0], [30.0, 8.0]])
    cls = np.array([0, 1, 2])
    loc = xy / 25.0
    b = np.arctan2(loc[:, 1], loc[:, 0]) + np.radians([2.0, 0.0, 0.0])
    q = np.column_stack([np.hypot(*loc.T) * np.cos(b), np.hypot(*loc.T) * np.sin(b)])
    cfg = SolverConfig.from_dict({})
    from test_likelihood import flat_model

    terms = []
    for model in (NoiseModel.constant(1.0, 0.3), NoiseModel.constant(3.0, 0.3)):
        pb = Problem(q, cls, xy, cls, False, cfg, model)
        pr = Priors(cfg, False, TrainingPriors(), n_ref=len(pb.r))
        parts = likelihood.pose_llr(pb, pr, flat_model(), 25.0, np.zeros((1, 2)), [0.0], [25.0])[2]
        terms.append(parts[0, likelihood.lk.PARTS.index("bearing")])
    # 2 deg at sigma 1: -2 - log(1 deg) ...; at sigma 3: -2/9 - log(3 deg): compare the detection's term
    expect = (-0.5 * 4.0 - math.log(math.radians(1.0))) - (-0.5 * 4.0 / 9.0 - math.log(math.radians(3.0)))
    expect += 2 * (-math.log(math.radians(1.0)) + math.log(math.radians(3.0)))  # the two exact ones
    assert terms[0] - terms[1] == pytest.approx(expect, abs=1e-6)


def test_without_a_fitted_model_the_settings_constant_model_is_used():
    cfg = SolverConfig.from_dict({"default_bearing_sigma_deg": 2.0, "default_log_range_sigma": 0.4})
    pb = Problem(np.ones((2, 2)), [0, 1], np.ones((2, 2)), [0, 1], False, cfg)
    assert pb.noise == NoiseModel.constant(2.0, 0.4)
    np.testing.assert_allclose(pb.terms.bearing_sigma, math.radians(2.0))
    np.testing.assert_allclose(pb.terms.log_range_sigma, 0.4 * cfg.msac_range_inflation)
    np.testing.assert_allclose(
        pb.refine_terms.log_range_sigma, 0.4 * cfg.msac_range_inflation * cfg.refine_range_inflation
    )


def test_the_noise_model_round_trips_and_refuses_other_bins(tmp_path):
    model = NoiseModel(BINNED.bearing_sigma_deg, BINNED.log_range_sigma, {"0": 0.19}, 8929)
    d = json.loads(json.dumps(model.to_dict()))
    assert NoiseModel.from_dict(d) == model
    d["range_edges_m"] = [0, 10, None]
    with pytest.raises(InputError, match="rule solver_priors refits"):
        NoiseModel.from_dict(d, "p.json")
    with pytest.raises(ValueError):
        NoiseModel((1.0,) * 3, (0.5,) * 3)
    assert len(RANGE_EDGES_M) - 1 == noise.N_BINS == len(BINNED.bearing_sigma_deg)


def test_an_old_priors_file_is_one_error_naming_its_format_and_the_rule(tmp_path):
    path = tmp_path / "whole.json"
    learned_priors.LearnedPriors((2.0, 0.5), None, noise=BINNED).write(path)
    doc = json.loads(path.read_text())
    assert doc["format"] == learned_priors.FORMAT == 2
    old = {k: v for k, v in doc.items() if k not in ("format", "noise")}
    old["distortion"] = {"0": 0.2}  # format 1 kept the bearing correction apart
    path.write_text(json.dumps(old))
    with pytest.raises(InputError, match=r"format 1 .*this solver reads format 2: rule solver_priors rewrites it"):
        learned_priors.LearnedPriors.read(path)
    doc["format"] = "2"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="format '2'"):
        learned_priors.LearnedPriors.read(path)


@pytest.mark.parametrize(
    ("key", "names"),
    [
        ("solver.bearing_sigma_deg", "solver.default_bearing_sigma_deg"),
        ("solver.refine_log_range_sigma", "solver.refine_range_inflation"),
        ("beyond.sequence.log_range_sigma", "solver.msac_range_inflation"),
    ],
)
def test_a_config_naming_a_replaced_noise_key_names_its_replacement(key, names):
    *sections, leaf = key.split(".")
    cfg: dict = {leaf: 1.0}
    for s in reversed(sections):
        cfg = {s: cfg}
    with pytest.raises(config.ConfigError, match=rf"'{key}' \(replaced by .*'{names}'"):
        config.resolve(cfg)


def test_the_fitted_priors_carry_one_noise_model_for_the_solver_and_the_likelihood():
    """A scene's learned priors give the solver's Problem the same model the likelihood reads, and the
    scene's bearing correction from it."""
    from test_likelihood import flat_model

    model = NoiseModel(BINNED.bearing_sigma_deg, BINNED.log_range_sigma, {"7": 0.3})
    lp = learned_priors.LearnedPriors((2.0, 0.5), None, flat_model(), noise=model)
    ref = pd.DataFrame(
        {"scene": [7, 7, 7], "obj_idx": [0, 1, 2], "class_id": [0, 1, 2], "x_m": [0.0, 5, 9], "y_m": [1.0, 3, 4]}
    )
    q = pd.DataFrame(columns=["split", "x_m", "y_m", "theta_deg", "ref_idx"])
    pr = solver.scene_priors(ref, q, None, lp)
    assert pr.noise is lp.noise and pr.bearing_k == pytest.approx(0.3)
