"""GT local maps (metres) have their own calibration with a null hypothesis (rule
solver_calibration_gt): fitted on real validation scenes, random layouts in metres come back
`ok` almost never, real queries almost always; the localizer reads it beside the depth priors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import published_scene

from flatlandia import config, localize, solver
from flatlandia.classes import CLASSES
from flatlandia.data import localmaps
from flatlandia.sequences import validation
from flatlandia.solver import nonsense

SCENES = ("3", "9", "12", "14")


@pytest.fixture(scope="module")
def fitted(flat_root):
    scenes = [published_scene(flat_root, s) for s in SCENES]
    learned, evidence = validation.gt_calibration(scenes, {}, seed=0)
    return scenes, learned, evidence


def test_gt_nonsense_is_drawn_at_the_real_querys_ranges():
    xy = np.array([[10.0, 0.0], [20.0, 5.0], [40.0, -3.0]])
    (n,) = nonsense.draw([[(xy, np.array([1, 2, 3]))]], [np.array([1, 2, 3])], 0, ("random_places",), metric=True)
    ranges = np.hypot(*n.xy.T)
    assert np.median(ranges) == pytest.approx(np.median(np.hypot(*xy.T)))
    (d,) = nonsense.draw([[(xy, np.array([1, 2, 3]))]], [np.array([1, 2, 3])], 0, ("random_places",))
    assert np.median(np.hypot(*d.xy.T)) == pytest.approx(1.0)


@pytest.mark.slow
def test_the_gt_calibration_holds_a_null_hypothesis_and_separates_real_from_random(fitted):
    scenes, learned, evidence = fitted
    assert learned is not None and learned.calibration.null_key is not None
    assert learned.verifier is None and learned.scale is None  # GT maps learn nothing else
    real = evidence["nonsense"] == ""
    assert real.sum() == sum((q["split"] == "val").sum() for _, q in scenes)
    threshold = config.section_defaults("solver")["answer_probability"]
    cfg = solver.SolverConfig.from_dict(None)
    ok = {"real": [], "random": []}
    rng = np.random.default_rng(7)
    for ref, q in scenes:
        priors = solver.scene_priors(ref, q, None, learned)
        for _, r in q[q["split"] == "test"].head(10).iterrows():
            xy, cls = localmaps.local_map(r, "gt"), np.asarray(r["classes"])
            unit = float(np.median(np.hypot(*xy.T)))
            for kind, qxy, qcls in (("real", xy, cls), ("random", unit * nonsense.random_layout(rng, len(cls)), cls)):
                best = solver.locate(
                    qxy, qcls, ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy(), True, cfg, priors
                ).best
                ok[kind].append(best is not None and localize.answer_status(best, threshold)["status"] == "ok")
    assert np.mean(ok["real"]) >= 0.85, np.mean(ok["real"])
    assert np.mean(ok["random"]) <= 0.05, np.mean(ok["random"])


@pytest.mark.slow
def test_the_localizer_reads_the_gt_calibration_beside_the_depth_priors(fitted, tmp_path):
    scenes, learned, _ = fitted
    ref, q = scenes[1]
    results = tmp_path / "results"
    (results / "9" / "maps").mkdir(parents=True)
    (results / "9" / "queries").mkdir(parents=True)
    (results / "solver" / "priors").mkdir(parents=True)
    ref.to_parquet(results / "9/maps/reference_map.parquet")
    q.to_parquet(results / "9/queries/queries.parquet")
    solver.LearnedPriors().write(results / "solver/priors/whole.json")
    m = localize.load_map(results / "9/maps/reference_map.parquet")
    rng = np.random.default_rng(3)
    cls = rng.choice(ref["class_id"].to_numpy(), 5)
    xy = 15.0 * nonsense.random_layout(rng, 5)
    query = {"objects": [{"class": CLASSES[int(c)], "x": float(x), "y": float(y)} for c, (x, y) in zip(cls, xy)]}
    without = localize.localize(m, query, "gt")
    assert without["priors"]["learned_from"] is None
    learned.write(results / "solver/priors/whole.gt.json")
    m = localize.load_map(results / "9/maps/reference_map.parquet")
    answer = localize.localize(m, query, "gt")
    assert answer["priors"]["learned_from"].endswith("whole.gt.json")
    assert answer["status"] != "ok"
    assert answer["probability"] is not None and answer["probability"] < without["probability"]
