"""The cities' map-size correction of the answers' probability (flatlandia.solver.calibration.MapSize,
rule city_calibration): fitted on a synthetic benchmark it recovers the known terms and calibrates
another draw; a map twice the size gets a lower probability for the same log-odds (a sure answer
and a scene map's size, or less, none); the city search applies it to its index's answers and not
to a fix's region;
`flatlandia localize --map <city index>` reads it beside the city folders, and a bad record is one
ERROR line."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from one_tile_city import write_one_tile_city
from test_city import CORNER, mirrored_city
from test_localize import query_file, run_cli, tiny_scene  # noqa: F401

from flatlandia import solver
from flatlandia.city import index, search
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError
from flatlandia.solver import calibration, learned_priors
from flatlandia.solver.calibration import Calibration, Logistic, MapSize, MapTerm

#: the synthetic benchmark's scene map size and true terms (one frame, sequences)
REFERENCE, FRAME, SEQUENCE = 100.0, MapTerm(0.1, 0.2), MapTerm(0.3, 0.15)


def synthetic_city_answers(rng, n: int) -> pd.DataFrame:
    """Answers calibrated on scene maps of REFERENCE objects, in maps of 100 to 100,000 objects:
    P(right) = sigmoid(z - log(map objects / REFERENCE) * max(0, shift - per_log_odds * z)), z the
    log-odds of ``probability``, the terms FRAME or SEQUENCE."""
    p = 1 / (1 + np.exp(-rng.normal(1.0, 2.0, n)))
    objects = rng.choice([REFERENCE, 2354.0, 10_000.0, 100_000.0], n)
    frames = rng.choice([1, 5], n)
    z, e = calibration.logit(p), np.log(objects / REFERENCE)
    z = np.where(frames > 1, z - SEQUENCE.loss(z, e), z - FRAME.loss(z, e))
    right = rng.random(n) < 1 / (1 + np.exp(-z))
    return pd.DataFrame({"frames": frames, "map_objects": objects, "probability": p, "right": right})


def test_the_correction_recovers_a_known_shift_and_calibrates_another_draw():
    rng = np.random.default_rng(7)
    val, test = synthetic_city_answers(rng, 8000), synthetic_city_answers(rng, 8000)
    fitted = calibration.fit_map_size(val, REFERENCE)
    for got, true in ((fitted.frame, FRAME), (fitted.sequence, SEQUENCE)):
        assert got.shift == pytest.approx(true.shift, abs=0.05) and got.per_log_odds == pytest.approx(
            true.per_log_odds, abs=0.05
        ), (got, true)
    for n in (2354.0, 100_000.0):
        for seq in (False, True):
            a = test[(test["map_objects"] == n) & ((test["frames"] > 1) == seq)]
            after = fitted.adjust(a["probability"], n, 5 if seq else 1)
            before = calibration.expected_calibration_error(a["probability"], a["right"])
            ece = calibration.expected_calibration_error(after, a["right"])
            assert ece <= 5.0 < before, (n, seq, ece, before)


def test_a_map_twice_the_size_gets_a_lower_probability():
    ms = MapSize(REFERENCE, MapTerm(0.2, 0.1), MapTerm(0.4, 0.1), 100)
    p = np.array([0.05, 0.5, 0.8, 0.85])  # log-odds below shift / per_log_odds = 2 (p 0.88)
    small, large = ms.adjust(p, 2 * REFERENCE), ms.adjust(p, 4 * REFERENCE)
    assert (large < small).all() and (small < p).all()
    z = calibration.logit(p)
    np.testing.assert_allclose(calibration.logit(small) - calibration.logit(large), (0.2 - 0.1 * z) * math.log(2))
    assert (ms.adjust(p, 4 * REFERENCE, frames=5) < large).all()  # sequences: their own, larger shift
    assert (np.diff(large) > 0).all()  # the order of a map's answers is kept
    sure = np.array([0.9, 0.99])  # a pool sure of itself stays sure, and nothing is ever raised
    np.testing.assert_array_equal(ms.adjust(sure, 4 * REFERENCE), sure)
    np.testing.assert_array_equal(ms.adjust(p, REFERENCE), p)  # a scene map's size: as calibrated
    np.testing.assert_array_equal(ms.adjust(p, 10), p)  # a smaller search (a fix's region): as calibrated
    few = calibration.fit_map_size(synthetic_city_answers(np.random.default_rng(0), 10), REFERENCE)
    assert few.frame == few.sequence == MapTerm(0.0, 0.0)  # too few answers: no correction


def test_the_record_round_trips_and_a_bad_one_is_refused(tmp_path):
    ms = MapSize(98.0, MapTerm(0.05, 0.2), MapTerm(0.25, 0.15), 1500)
    path = tmp_path / "calibration.json"
    files.write_json({"map_size": ms.to_dict(), "split": "val"}, path)
    assert learned_priors.read_map_size(path) == ms
    lp = learned_priors.LearnedPriors((2.0, 0.5)).with_map_size(ms)
    lp.write(tmp_path / "whole.json")
    assert learned_priors.LearnedPriors.read(tmp_path / "whole.json").calibration.map_size == ms
    for key, value, says in [
        ("frame", {"shift": -0.5, "per_log_odds": 0.1}, "map_size frame shift must be a finite number in [0, 2]"),
        ("sequence", {"shift": 0.1, "per_log_odds": float("nan")}, "map_size sequence per_log_odds must be a finite"),
        ("sequence", 0.3, "map_size sequence must be an object with shift and per_log_odds"),
        ("reference_objects", 0, "map_size reference_objects must be a finite number in [1,"),
        ("answers", "many", "map_size answers must be a count"),
    ]:
        path.write_text(json.dumps({"map_size": {**ms.to_dict(), key: value}}))
        with pytest.raises(InputError, match=says.replace("[", r"\[")):
            learned_priors.read_map_size(path)
    path.write_text(json.dumps({"frame": 0.1}))
    with pytest.raises(InputError, match="map_size object"):
        learned_priors.read_map_size(path)


def _priors(map_size: MapSize | None) -> solver.LearnedPriors:
    """A scale prior and a calibration of moderate probabilities (so that a shift shows)."""
    cal = Calibration(Logistic(0.0, (0.3, 0.0, 0.0, 0.0), 100), Logistic(0.0, (0.3, 0.0, 0.0, 0.0), 100))
    return solver.LearnedPriors(scale=(np.log(17.0), 0.5), calibration=cal).with_map_size(map_size)


def test_the_city_search_lowers_its_index_answers_not_a_fix():
    ref, views = mirrored_city()
    ix = index.build(ref, views)
    q_gt = np.array([[x, y] for _, x, y in CORNER])
    q, q_cls = q_gt / np.median(np.hypot(*q_gt.T)), np.array([c for c, _, _ in CORNER])
    cfg, settings = search.SearchConfig.from_dict({"regions": 2}), solver.SolverConfig.from_dict({"covis_weight": 0.0})
    ms = MapSize(2.0, MapTerm(2.0, 0.0), MapTerm(2.0, 0.0), 100)  # the 12-object city is 6 times this "scene map"
    plain = search.search_city(ix, q, q_cls, cfg, settings, _priors(None), alternatives=2)
    lowered = search.search_city(ix, q, q_cls, cfg, settings, _priors(ms), alternatives=2)
    shift = 2.0 * math.log(ix.n_objects / 2.0)
    for a, b in zip([plain.solution, *plain.alternatives], [lowered.solution, *lowered.alternatives]):
        assert (a.x, a.y, a.theta) == (b.x, b.y, b.theta)  # the same answer, ranked alike
        assert calibration.logit(b.probability) == pytest.approx(calibration.logit(a.probability) - shift, abs=1e-6)
    fix = solver.Fix(0.5, 0.3, 20.0)
    at_fix = [search.search_city(ix, q, q_cls, cfg, settings, _priors(m), fix=fix).solution for m in (None, ms)]
    assert at_fix[0].probability == at_fix[1].probability  # a fix's region is not the city


def test_localize_reads_the_record_beside_the_city_folders(tiny_scene, tmp_path, capsys):  # noqa: F811
    ref, _, q = tiny_scene
    results = tmp_path / "results"
    city = results / "city" / "1"
    cref, cq = write_one_tile_city(ref, q, city)
    _priors(None).write(results / "solver" / "priors" / "whole.json")
    query = query_file(tmp_path / "q.json", cq[cq["split"] == "test"].iloc[0], "depth")
    args = ["--map", city / "index", "--query", query, "--map-type", "depth"]
    status, text = run_cli(capsys, *args)
    plain = json.loads(text)
    assert status == 0 and plain["found"] and plain["priors"]["map_size_from"] is None
    record = results / "city" / "calibration.json"
    files.write_json({"map_size": MapSize(2.0, MapTerm(2.0, 0.0), MapTerm(2.0, 0.0), 100).to_dict()}, record)
    status, text = run_cli(capsys, *args)
    out = json.loads(text)
    assert status == 0 and out["priors"]["map_size_from"] == str(record)
    assert (out["x_m"], out["y_m"]) == (plain["x_m"], plain["y_m"]) and out["probability"] < plain["probability"]
    bad = MapSize(2.0, MapTerm(2.0, 0.0), MapTerm(2.0, 0.0), 100).to_dict()
    bad["frame"]["shift"] = float("nan")
    record.write_text(json.dumps({"map_size": bad}))
    status, text = run_cli(capsys, *args)
    lines = text.strip().splitlines()
    assert status == 1 and len(lines) == 1 and lines[0].startswith(f"ERROR: {record}: map_size frame"), text
