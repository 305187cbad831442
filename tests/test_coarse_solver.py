"""Training-free coarse proposals from the geometric solver (flatlandia.coarse.solver_proposals)."""

import numpy as np
import pandas as pd
import pytest
from snakemake_runner import smk

from flatlandia import config, geo, solver
from flatlandia.coarse import evaluation, solver_proposals

CAM, THETA = np.array([10.0, -20.0]), 0.6


def _street(seed=0, n_ref=80, n_cls=4):
    """A 400 m map of random objects, six of them in view of a camera at CAM (GT map, noise-free
    depth map of those six)."""
    rng = np.random.default_rng(seed)
    seen = np.column_stack([rng.uniform(8, 40, 6), rng.uniform(-0.6, 0.6, 6)])
    seen[:, 1] *= seen[:, 0]
    ref = np.vstack([geo.local_to_world(seen, CAM, THETA), rng.uniform(-200, 200, (n_ref - 6, 2))])
    cls = rng.integers(0, n_cls, n_ref)
    vis = np.arange(6)
    depth = seen / np.median(np.linalg.norm(seen, axis=1))
    return solver_proposals.Candidates(ref, cls), vis, seen, depth, cls[vis]


def test_solver_proposal_holds_the_query_where_the_whole_map_is_mostly_wrong():
    cand, vis, gt, depth, qc = _street()
    cfg = solver_proposals.SolverProposalConfig()
    for q, metric in ((gt, True), (depth, False)):
        hyps = solver_proposals.hypotheses(q, qc, cand, metric, alternatives=1)
        n_lm = solver_proposals.propose(hyps, q, qc, cand, "N_LM", cfg)
        assert list(n_lm) == sorted(vis)  # exactly the query's objects
        assert evaluation.proposal_metrics(n_lm, vis)["precision"] == 1.0
        r30 = solver_proposals.propose(hyps, q, qc, cand, "R_30", cfg)
        assert set(vis) <= set(r30) and np.isin(cand.cls[r30], qc).all()
        assert evaluation.proposal_metrics(np.arange(len(cand.xy)), vis)["precision"] < 0.1  # the whole map
        np.testing.assert_allclose(solver_proposals.placed(hyps[0][0], q), cand.xy[vis], atol=1e-3)


def test_fixed_size_strategies_keep_to_the_query_classes_and_size():
    cand, vis, gt, depth, qc = _street(seed=1)
    cfg = solver_proposals.SolverProposalConfig()
    hyps = solver_proposals.hypotheses(depth, qc, cand, False, alternatives=1)
    two = solver_proposals.propose(hyps, depth, qc, cand, "2N_LM", cfg)
    assert len(two) == 2 * len(vis) and set(vis) <= set(two) and np.isin(cand.cls[two], qc).all()
    few = solver_proposals.Candidates(cand.xy[vis], cand.cls[vis])  # fewer objects of its classes than 2N
    hyps = solver_proposals.hypotheses(depth, qc, few, False, alternatives=1)
    assert list(solver_proposals.propose(hyps, depth, qc, few, "2N_LM", cfg)) == list(range(len(vis)))
    assert len(solver_proposals.propose([], depth, qc, cand, "R_30", cfg)) == 0
    with pytest.raises(ValueError):
        solver_proposals.propose(hyps, depth, qc, few, "R_50", cfg)


def test_an_alternative_pose_rescues_a_wrong_best_pose():
    """Two identical copies of a street 200 m apart, the query taken at the second copy; a training
    camera exactly at the first copy's pose and one 4 m off the second's make the solver's best
    pose the wrong copy. Its runner-up (solved without the objects the best matched) is right, so
    R_30 holds the query when the runner-up is within ``cost_gap`` of the best, not otherwise."""
    rng = np.random.default_rng(3)
    pattern = np.column_stack([rng.uniform(8, 40, 6), rng.uniform(-15, 15, 6)])
    cls = rng.integers(0, 4, 6)
    cand = solver_proposals.Candidates(
        np.vstack([pattern, pattern + [200.0, 0.0]]),
        np.concatenate([cls, cls]),
        solver.TrainingPriors(cameras=np.array([[0.0, 0.0, 0.0], [204.0, 0.0, 0.0]])),
    )
    truth = np.arange(6, 12)
    hyps = solver_proposals.hypotheses(pattern, cls, cand, True, alternatives=2)
    (best, _), (runner_up, _) = hyps
    assert np.hypot(best.x, best.y) < 1e-3 and np.hypot(runner_up.x - 200.0, runner_up.y) < 1e-3
    gap = runner_up.cost - best.cost
    assert gap > 0
    wide = solver_proposals.SolverProposalConfig(alternatives=2, cost_gap=gap + 1.0)
    narrow = solver_proposals.SolverProposalConfig(alternatives=2, cost_gap=gap / 2)
    r30 = solver_proposals.propose(hyps, pattern, cls, cand, "R_30", wide)
    assert evaluation.proposal_metrics(r30, truth)["success"] and list(r30) == list(range(12))
    r30 = solver_proposals.propose(hyps, pattern, cls, cand, "R_30", narrow)
    assert not evaluation.proposal_metrics(r30, truth)["success"] and list(r30) == list(range(6))
    n_lm = solver_proposals.propose(hyps, pattern, cls, cand, "N_LM", wide)  # the best pose only
    assert list(n_lm) == list(range(6))


def test_priors_mask_what_training_cameras_saw_over_the_candidate_rows():
    ref = pd.DataFrame({"obj_idx": [4, 7, 9], "class_id": [1, 2, 1], "x_m": [0.0, 1.0, 2.0], "y_m": [0.0, 0.0, 1.0]})
    seen = solver.priors.seen_mask(ref["obj_idx"], [np.array([9, 4]), np.array([7])])
    cand = solver_proposals.scene_candidates(ref, solver.TrainingPriors(np.zeros((2, 3)), seen))
    assert cand.priors.seen.tolist() == [[True, False, True], [False, True, False]]
    assert cand.priors.rows([2, 0]).seen.tolist() == [[True, True], [False, False]]  # a proposal's rows
    assert cand.priors.without_cameras(np.array([False, True])).seen.tolist() == [[False, True, False]]
    assert solver_proposals.scene_candidates(ref).priors is None


def test_config_comes_from_the_schema_and_is_strict():
    defaults = config.section_defaults("coarse.solver")
    assert solver_proposals.SolverProposalConfig().to_dict().items() <= defaults.items()
    assert defaults["fine_strategy"] in solver_proposals.STRATEGIES  # read by the fine runs' input function
    with pytest.raises(ValueError, match="alternatives"):
        solver_proposals.SolverProposalConfig.from_dict({"alternativs": 2})


@pytest.fixture(scope="module")
def scene(scene9):
    """Scene 9's reference map and queries, built from the published data."""
    return scene9


@pytest.mark.slow  # the published data (flat_root)
def test_scene_proposals_on_a_real_scene_feed_table_3(scene):
    """Every query of scene 9 (no priors: the solver alone): on GT maps N_LM is the matched objects;
    the rows have the shape of the retrieval models' proposals and summarise into Table 3 rows."""
    ref, q = scene
    cfg = solver_proposals.SolverProposalConfig()
    cand = solver_proposals.scene_candidates(ref)
    rows = pd.concat([solver_proposals.scene_proposals(ref, q, mt, cand, cfg) for mt in ("gt", "depth")])
    assert len(rows) == 2 * len(solver_proposals.STRATEGIES) * len(q)
    assert {"scene", "token", "map_type", "strategy", "proposal", "precision", "recall", "success"} <= set(rows.columns)
    assert set(rows["proposal"].explode().dropna().astype(int)) <= set(ref["obj_idx"])
    gt = rows[(rows["map_type"] == "gt") & (rows["strategy"] == "N_LM")]
    assert gt["precision"].mean() > 0.95 and gt["success"].mean() > 0.9
    table = evaluation.summarise(rows).set_index(["loss", "strategy", "map_type"])
    assert table.loc[("Solver", "R_30", "depth"), "success"] >= table.loc[("Solver", "N_LM", "depth"), "success"]
    assert np.isnan(table.loc[("Solver", "R_30", "gt"), "paper_success"])
    assert "| Solver | R_30 |" in evaluation.render_markdown(table.reset_index())


def _jobs(out: str, rule: str) -> int:
    """Jobs of one rule in a dry run's job stats (0 when absent)."""
    return next((int(ln.split()[1]) for ln in out.splitlines() if ln.split()[:1] == [rule]), 0)


@pytest.mark.slow  # the published data (flat_root)
def test_fine_runs_on_the_solver_proposals_train_nothing_new(repo, flat_root, tmp_path):
    """The MLP on the solver's boxes is the GT-BB-trained one, and the solver's proposals need no
    coarse model: adding `coarse-solver` to the default runs adds no training job."""
    res = smk(
        repo,
        tmp_path,
        "-n",
        "results/fine/mlp_depth_coarse-solver/summary.json",
        "--config",
        f"flatlandia_root={flat_root}",
    )
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    assert "results/coarse/solver/proposals.parquet" in out
    assert "results/fine/models/mlp_depth_gtbb/checkpoint.pt" in out
    assert _jobs(out, "coarse_solver") == 1 and _jobs(out, "coarse_train") == 0 and "mlp_depth_coarse/" not in out
    counts = {}
    for proposals in ("[gtbb,coarse-simtrip]", "[gtbb,coarse-simtrip,coarse-solver]"):
        res = smk(
            repo,
            tmp_path,
            "-n",
            "all",
            "--config",
            f"flatlandia_root={flat_root}",
            f"fine={{'runs': {{'proposals': {proposals}}}}}",
        )
        assert res.returncode == 0, res.stderr[-2000:]
        counts[proposals] = {
            r: _jobs(res.stdout, r) for r in ("fine_train", "coarse_train", "fine_eval", "coarse_solver")
        }
    before, after = counts.values()
    assert after["fine_train"] == before["fine_train"] and after["coarse_train"] == before["coarse_train"]
    assert after["fine_eval"] == before["fine_eval"] + 4 and after["coarse_solver"] == 1
