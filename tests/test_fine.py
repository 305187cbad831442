"""Fine 3DoF localization: the geometric solver, the learned baselines, metrics."""

import math

import numpy as np
import pandas as pd
import pytest
import torch
from snakemake_runner import smk

from flatlandia import checkpoints, geo, proposals, solver
from flatlandia.benchmark import fine_rows, metrics, solver_runs
from flatlandia.fine import evaluation, fine_table, models, training
from flatlandia.solver import problem, scoring

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def scene(scene9):
    """Scene 9's reference map and queries, built from the published data."""
    return scene9


# ----------------------------------------------------------------------------- solver


@pytest.mark.slow  # the published data (flat_root)
def test_solver_exact_on_gt_maps_of_a_real_scene(scene):
    ref, q = scene
    props = proposals.gtbb_proposals(ref, q)
    e = solver_runs.evaluate_solver(ref, q, props, "gt")
    assert len(e) == len(q)
    assert (e["error_m"] < 0.1).mean() >= 0.99
    # the solver's matches, per local-map object, are the published ones (the figures link them)
    same = [list(m) == [int(i) for i in t] for m, t in zip(e["matched_obj_idx"], q["ref_idx"])]
    assert np.mean(same) >= 0.99
    assert e["error_deg"].median() < 1e-6


@pytest.mark.slow  # the published data (flat_root)
def test_solver_exact_on_gt_maps_whole_map(scene):
    ref, q = scene
    q = q.iloc[:20]
    e = solver_runs.evaluate_solver(ref, q, proposals.whole_map_proposals(ref, q), "gt")
    assert (e["error_m"] < 0.1).mean() >= 0.95


def _synthetic(rng, n_ref=40, n_q=6, noise_deg=0.0, outliers=0, n_cls=4, range_noise=0.2):
    ref = rng.uniform(-60, 60, (n_ref, 2))
    cls = rng.integers(0, n_cls, n_ref)
    cam, theta = np.array([3.0, -4.0]), 0.7
    local = geo.world_to_local(ref, cam, theta)
    vis = np.flatnonzero((local[:, 0] > 2) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) < 1.0))[:n_q]
    ql = local[vis].copy()
    bearing = np.arctan2(ql[:, 1], ql[:, 0]) + np.radians(noise_deg) * rng.standard_normal(len(ql))
    rng_ = np.linalg.norm(ql, axis=1) * np.exp(range_noise * rng.standard_normal(len(ql)))
    depth = np.column_stack([np.cos(bearing), np.sin(bearing)]) * rng_[:, None]
    for k in range(outliers):  # a wrong bearing
        b = bearing[k] + np.radians(25.0)
        depth[k] = np.array([np.cos(b), np.sin(b)]) * rng_[k]
    depth /= np.median(np.linalg.norm(depth, axis=1))
    return ref, cls, cam, theta, ql, cls[vis], depth, vis


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_solver_synthetic_exact_metric_and_bearing_only(seed):
    rng = np.random.default_rng(seed)
    ref, cls, cam, theta, ql, qc, depth, vis = _synthetic(rng, range_noise=0.0)
    s = solver.solve(ql, qc, ref, cls, metric=True)
    assert np.hypot(s.x - cam[0], s.y - cam[1]) < 1e-6 and abs(geo.wrap_angle(s.theta - theta)) < 1e-8
    assert s.confidence == pytest.approx(1.0)
    # noise-free but unscaled depth map: exact
    s = solver.solve(depth, qc, ref, cls, metric=False)
    assert np.hypot(s.x - cam[0], s.y - cam[1]) < 1e-4 and abs(geo.wrap_angle(s.theta - theta)) < 1e-6
    # exact bearings, noisy ranges: bearings carry it (weak range terms pull by centimetres)
    ref, cls, cam, theta, ql, qc, depth, vis = _synthetic(np.random.default_rng(seed), range_noise=0.2)
    s = solver.solve(depth, qc, ref, cls, metric=False)
    assert np.hypot(s.x - cam[0], s.y - cam[1]) < 0.3 and abs(np.degrees(geo.wrap_angle(s.theta - theta))) < 0.3


@pytest.mark.parametrize("metric", [False, True])
def test_compiled_scoring_equals_padded_numpy_costs(metric):
    """The compiled scoring loops (early bearing rejection, flat candidates) give the same capped
    MSAC data cost, inliers and inlier matches as the padded (C, M, K) numpy costs."""
    rng = np.random.default_rng(3)
    ref, cls = rng.uniform(-100, 100, (150, 2)), rng.integers(0, 6, 150)
    q, qc = rng.uniform(1, 30, (7, 2)), np.r_[rng.integers(0, 6, 6), 9]  # class 9: no candidates
    pb = problem.Problem(q, qc, ref, cls, metric, solver.SolverConfig(position_sigma_m=5.0))  # inliers by chance
    t, th, s = rng.uniform(-100, 100, (4000, 2)), rng.uniform(-np.pi, np.pi, 4000), rng.uniform(2, 50, 4000)
    total, inl, match = scoring.data_cost(pb, t, th, s)
    cost = scoring.padded_costs(pb, t, th, s)
    best = cost.argmin(2)
    bc = np.take_along_axis(cost, best[..., None], 2)[..., 0]
    tau2 = pb.cfg.tau**2
    np.testing.assert_allclose(total, np.minimum(bc, tau2).sum(1), rtol=1e-4, atol=1e-4)
    ok = np.abs(bc - tau2) > 1e-3  # float32 reference: leave exact ties with the cap aside
    assert (inl == (bc < tau2))[ok].all() and inl.sum() > 100
    ref_match = scoring.padded_candidates(pb)[0][np.arange(pb.m)[None], best]
    assert (match[inl] == ref_match[inl]).all()
    assert not inl[:, -1].any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_solver_synthetic_noise_and_outliers(seed):
    rng = np.random.default_rng(10 + seed)
    ref, cls, cam, theta, ql, qc, depth, vis = _synthetic(rng, n_q=8, noise_deg=0.5, outliers=1)
    s = solver.solve(depth, qc, ref, cls, metric=False)
    assert np.hypot(s.x - cam[0], s.y - cam[1]) < 2.0
    assert abs(np.degrees(geo.wrap_angle(s.theta - theta))) < 2.0
    matched = dict(s.inliers)
    assert matched.get(0) != vis[0]  # the wrong bearing is not matched to its true object
    assert sum(matched.get(k) == vis[k] for k in range(1, len(vis))) >= 6  # the others are


@pytest.mark.parametrize("seen_copy", [0, 1])
def test_covisibility_prior_breaks_a_repeated_pattern(seen_copy):
    """Two identical copies of a street scene 200 m apart, a training camera in front of each:
    geometry alone cannot tell them apart; the co-visibility cost picks the copy whose objects the
    nearby training camera saw."""
    rng = np.random.default_rng(3)
    pattern = np.column_stack([rng.uniform(8, 40, 6), rng.uniform(-15, 15, 6)])
    cls = rng.integers(0, 4, 6)
    ref = np.vstack([pattern, pattern + [200.0, 0.0]])
    ref_cls = np.concatenate([cls, cls])
    depth = pattern / np.median(np.linalg.norm(pattern, axis=1))  # camera at a copy's origin, heading 0
    prior = np.array([[0.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    seen = np.zeros((2, 12), bool)
    seen[seen_copy, 6 * seen_copy : 6 * seen_copy + 6] = True  # only one camera saw its copy
    cfg = {"covis_weight": 2.0}
    s = solver.solve(depth, cls, ref, ref_cls, metric=False, config=cfg, priors=solver.TrainingPriors(prior, seen))
    assert np.hypot(s.x - 200.0 * seen_copy, s.y) < 1e-3 and abs(geo.wrap_angle(s.theta)) < 1e-6
    assert sorted(m for _, m in s.inliers) == list(range(6 * seen_copy, 6 * seen_copy + 6))


@pytest.mark.slow  # the published data (flat_root)
def test_training_priors_come_from_the_training_split_only(scene):
    _, q = scene
    prior, seen = solver.priors.training_priors(q, {"covis_weight": 2.0})
    train = q[q["split"] == "train"]
    assert len(prior) == len(seen) == len(train)
    assert np.allclose(prior[:, :2], train[["x_m", "y_m"]].to_numpy())
    assert solver.priors.training_priors(q, {"camera_prior": False}) == (None, None)
    assert solver.priors.training_priors(q, {"covis_weight": 0.0})[1] is None  # no co-visibility cost: no sets


def test_solver_returns_none_without_candidates():
    assert solver.solve(np.array([[1.0, 0.0], [2.0, 1.0]]), [1, 2], np.zeros((0, 2)), np.zeros(0, int)) is None


def test_fit_scale():
    mu, sd = solver.fit_scale([np.array([[10.0, 0.0], [0.0, 10.0]]), np.array([[30.0, 0.0]])])
    assert mu == pytest.approx(np.mean(np.log([10.0, 30.0])))
    assert sd > 0


# ----------------------------------------------------------------------------- metrics


def test_pose_errors_wrap_around():
    e_m, e_deg = geo.pose_errors(3.0, 4.0, math.radians(179.0), 0.0, 0.0, math.radians(-179.0))
    assert e_m == pytest.approx(5.0) and e_deg == pytest.approx(2.0)


def test_summary_on_hand_made_errors():
    e = pd.DataFrame(
        {
            "error_m": [0.1, 0.8, 4.0, 9.0, 50.0, np.inf],
            "error_deg": [1.0, 4.0, 9.0, 30.0, 1.0, 180.0],
            "solvable": [True] * 5 + [False],
            "seconds": [0.01] * 6,
            "error_paper_m": [0.0] * 6,
        }
    )
    s = metrics.summarise(e)
    assert s["pct_0.5m_2deg"] == pytest.approx(100 / 6)
    assert s["pct_1m_5deg"] == pytest.approx(200 / 6)
    assert s["pct_5m_10deg"] == pytest.approx(300 / 6)
    assert s["pct_10m_20deg"] == pytest.approx(300 / 6)  # 9 m but 30 deg is out
    assert s["failure_pct"] == pytest.approx(100 / 6)
    assert s["gross_pct"] == pytest.approx(200 / 6)  # inf counts as gross
    assert s["median_m"] == pytest.approx(6.5)
    assert s["mean_query_s"] == pytest.approx(0.01)


def test_solvable_counts_class_multiset():
    assert metrics.solvable([1, 1, 2], [1, 1, 2, 5])
    assert not metrics.solvable([1, 1, 2], [1, 2, 5])  # only one object of class 1 for two query objects
    assert not metrics.solvable([1, 2, 3], [4, 5, 6])


def test_gtbb_box_and_paper_units():
    ref_xy = np.array([[0.0, 0.0], [10.0, 10.0], [10.5, 5.0], [12.0, 5.0], [-0.4, 5.0]])
    idx = proposals.gtbb_indices(ref_xy, [0, 1], [10.0, 0.0])
    assert set(idx) == {0, 1, 2, 4}  # box [0,10]^2 enlarged 10%: [-0.5, 10.5]
    mpu = metrics.metres_per_unit(45.0)
    assert metrics.paper_metres(mpu, 45.0) == pytest.approx(215.0)


def test_markdown_table_layout():
    rows = [
        dict(
            method="MLP",
            map_type=mt,
            strategy="GT-BB",
            median_m=5.0,
            median_deg=9.0,
            median_paper_m=6.0,
            mean_query_s=0.002,
            failure_pct=0.0,
            gross_pct=1.0,
            **{c: 10.0 for c in metrics.THRESHOLD_COLUMNS},
        )
        for mt in ("gt", "depth")
    ]
    md = fine_table.render_markdown(fine_rows.table_rows(rows))
    assert "Table 4" in md and "| MLP | GT-BB |" in md and "13.3" in md  # the paper's depth MLP median


# ----------------------------------------------------------------------------- learned models


def _toy_samples(n, cfg, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        ref = rng.uniform(-50, 50, (12, 2))
        cls = rng.integers(0, 5, 12)
        cam, th = rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)
        local = geo.world_to_local(ref[:5], cam, th)
        q = local / np.median(np.linalg.norm(local, axis=1)) if cfg.map_type == "depth" else local
        out.append(models.make_sample(q, cls[:5], ref, cls, cfg, cam, th))
    return out


@pytest.mark.parametrize("name", models.MODELS)
def test_models_forward_backward_shapes(name):
    cfg = models.FineTrainConfig(model=name, hidden=16, heads=2, rounds=1)
    samples = _toy_samples(5, cfg)
    model = models.build_model(cfg)
    batch = models.Batch.from_data_list(samples)
    out = model(batch)
    assert out.shape == (5, 3)
    loss = training.pose_loss(out, batch.y, cfg.angle_weight)
    loss.backward()
    assert all(p.grad is not None for p in model.parameters() if p.requires_grad)


@pytest.mark.parametrize("name", models.MODELS)
def test_batching_equals_one_by_one(name):
    cfg = models.FineTrainConfig(model=name, hidden=16, heads=2, rounds=1)
    samples = _toy_samples(4, cfg)
    torch.manual_seed(0)
    model = models.build_model(cfg).eval()
    with torch.no_grad():
        together = model(models.Batch.from_data_list(samples))
        alone = torch.cat([model(models.Batch.from_data_list([s])) for s in samples])
    assert torch.allclose(together, alone, atol=1e-5)


@pytest.mark.parametrize("name", ["MLP", "MLP+ATT"])
def test_dense_row_selection_equals_graph_batch(name):
    """The MLPs train on padded rows selected from the whole split: same outputs as collated graphs."""
    cfg = models.FineTrainConfig(model=name, hidden=16, heads=2)
    samples = _toy_samples(6, cfg)
    samples[2] = models.make_sample(np.zeros((3, 2)), [1, 2, 3], np.ones((30, 2)), np.arange(30) % 5, cfg, (0, 0), 0.1)
    torch.manual_seed(0)
    model = models.build_model(cfg).eval()
    dense = models.dense_maps(samples)
    pick = [4, 2, 0]
    sel = dense[pick]
    assert sel.r_xy.shape[1] == 30 and sel.q_mask.sum() == 5 + 3 + 5  # trimmed to the longest selected map
    with torch.no_grad():
        assert torch.allclose(model(sel), model(models.Batch.from_data_list([samples[i] for i in pick])), atol=1e-5)
    gen_a, gen_b = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    cfg.map_type = "depth"
    aug_d = training.augment(dense, cfg, gen_a)
    aug_g = training.augment(models.Batch.from_data_list(samples), cfg, gen_b)
    assert torch.allclose(aug_d.y, aug_g.y)
    assert torch.allclose(aug_d.r_xy[dense.r_mask], aug_g.local[~aug_g.is_q], atol=1e-6)
    assert torch.allclose(aug_d.q_xy[dense.q_mask], aug_g.local[aug_g.is_q], atol=1e-6)


def test_loss_and_angle_wrap():
    a = torch.tensor([math.radians(179.0)])
    b = torch.tensor([math.radians(-179.0)])
    assert training.angle_distance(a, b).item() == pytest.approx(math.radians(2.0), abs=1e-6)
    pred = torch.tensor([[0.3, 0.4, 0.1]])
    assert training.pose_loss(pred, torch.tensor([[0.0, 0.0, 0.1]]), 1.0).item() == pytest.approx(0.5, abs=1e-6)


def test_augmentation_is_a_rigid_motion_of_region_and_target():
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", aug_depth_scale=0.0)
    samples = _toy_samples(3, cfg)
    batch = models.Batch.from_data_list(samples)
    aug = training.augment(batch, cfg, torch.Generator().manual_seed(0))
    q = batch.is_q
    assert torch.allclose(aug.local[q], batch.local[q])  # query stays in its camera frame
    for g in range(3):
        r = (~q) & (batch.batch == g)
        # the region seen from the (augmented) camera is unchanged: the pose moved with the map
        before = geo.world_to_local(batch.local[r].numpy(), batch.y[g, :2].numpy(), float(batch.y[g, 2]))
        after = geo.world_to_local(aug.local[r].numpy(), aug.y[g, :2].numpy(), float(aug.y[g, 2]))
        assert np.allclose(before, after, atol=1e-5)


def test_short_training_reduces_loss_and_is_deterministic(tmp_path):
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=32, epochs=8, batch_size=16, lr=3e-3, augment=False)
    train = _toy_samples(64, cfg, seed=1)
    val = _toy_samples(16, cfg, seed=2)
    res = training.train(train, val, cfg)
    losses = [h["train_loss"] for h in res["history"]]
    assert losses[-1] < losses[0]
    assert res["best_val_median_m"] <= res["history"][0]["val_median_m"]
    res2 = training.train(train, val, cfg)
    assert [h["train_loss"] for h in res2["history"]] == losses  # seeded, deterministic on CPU
    path = tmp_path / "ck.pt"
    checkpoints.save_checkpoint(res, path)
    model, cfg2 = checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)
    assert cfg2 == cfg
    assert np.allclose(models.predict(model, val), models.predict(res["model"], val), atol=1e-6)


def test_warm_start_continues_from_the_given_weights(tmp_path):
    """Training on simulated coarse proposals starts from the GT-BB model (fine.coarse_training.warm_start):
    with a vanishing step it keeps that model's predictions; without the weights it does not."""
    cfg = models.FineTrainConfig(
        model="MLP", map_type="gt", hidden=32, epochs=30, batch_size=16, lr=3e-3, augment=False
    )
    train, val = _toy_samples(64, cfg, seed=1), _toy_samples(16, cfg, seed=2)
    first = training.train(train, val, cfg)
    short = models.FineTrainConfig(**{**cfg.to_dict(), "epochs": 1, "lr": 1e-12})
    cold = training.train(train, val, short)
    warm = training.train(train, val, short, init_state=first["state_dict"])
    assert np.allclose(models.predict(warm["model"], val), models.predict(first["model"], val), atol=1e-4)
    assert warm["history"][0]["val_median_m"] == pytest.approx(first["best_val_median_m"], rel=1e-3)
    assert not np.allclose(models.predict(cold["model"], val), models.predict(first["model"], val), atol=1e-2)


@pytest.mark.slow  # the published data (flat_root)
def test_coarse_training_starts_from_the_gtbb_model_unless_told_otherwise(repo, flat_root, tmp_path):
    target = "results/fine/models/mlp_depth_coarse/checkpoint.pt"
    res = smk(repo, tmp_path, "-n", "-p", target, "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "results/fine/models/mlp_depth_gtbb/checkpoint.pt" in res.stdout
    off = "fine={'coarse_training': {'warm_start': False}}"
    res = smk(repo, tmp_path, "-n", target, "--config", f"flatlandia_root={flat_root}", off)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "mlp_depth_gtbb/checkpoint.pt" not in res.stdout


@pytest.mark.slow  # the published data (flat_root)
def test_learned_model_on_real_scene_samples(scene):
    ref, q = scene
    cfg = models.FineTrainConfig(model="GAT", map_type="depth", hidden=16, heads=2, rounds=1, epochs=1)
    tr = q[q["split"] == "train"]
    samples, kept = models.samples_from_queries(ref, tr, proposals.gtbb_proposals(ref, tr), cfg)
    assert len(samples) == len(kept) == len(tr) > 3
    model = models.build_model(cfg)
    e = evaluation.evaluate_model(model, cfg, ref, tr.iloc[:4], proposals.gtbb_proposals(ref, tr.iloc[:4]))
    assert len(e) == 4 and np.isfinite(e["error_m"]).all()


@pytest.mark.slow  # the published data (flat_root)
def test_external_proposal_table_and_failure_rate(scene):
    """A coarse-style proposal table (scene, token, strategy, proposal): too-small proposals count in F%."""
    ref, q = scene
    q = q.iloc[:6]
    good = proposals.gtbb_proposals(ref, q)
    props = good.copy()
    props["strategy"] = "2N_LM"
    props.loc[0, "proposal"] = [int(ref["obj_idx"].iloc[0])]  # one object: cannot hold a solution
    e = solver_runs.evaluate_solver(ref, q, props, "gt")
    assert not e.loc[0, "solvable"] and e.loc[1:, "solvable"].all()
    assert metrics.summarise(e)["failure_pct"] == pytest.approx(100 / 6)
    assert (e.loc[1:, "error_m"] < 0.1).all() and set(e["strategy"]) == {"2N_LM"}


@pytest.mark.slow  # the published data (flat_root)
def test_simulated_coarse_proposals_look_like_2n_lm(scene):
    ref, q = scene
    props = proposals.simulated_coarse_proposals(ref, q, np.random.default_rng(0))
    again = proposals.simulated_coarse_proposals(ref, q, np.random.default_rng(0))
    assert props["proposal"].map(list).tolist() == again["proposal"].map(list).tolist()  # seeded
    cls = dict(zip(ref["obj_idx"].astype(int), ref["class_id"].astype(int)))
    recall = []
    for r, p in zip(q.itertuples(index=False), props["proposal"]):
        true, prop = {int(i) for i in r.ref_idx}, [int(o) for o in p]
        assert len(set(prop)) == len(prop) and true & set(prop)  # distinct, at least one true object
        assert len(prop) <= max(2 * len(true), 1)
        assert {cls[o] for o in set(prop) - true} <= {int(c) for c in r.classes}  # wrong objects of seen classes
        recall.append(len(true & set(prop)) / len(true))
    assert 0.3 < np.mean(recall) < 0.75


@pytest.mark.slow  # the published data (flat_root)
def test_crop_to_densest_keeps_the_densest_group(scene):
    """Two groups of objects 200 m apart: the crop keeps the larger one, whole, and nothing else."""
    ref = pd.DataFrame(
        {
            "obj_idx": np.arange(7),
            "x_m": [0, 5, 10, 12, 200, 205, 210.0],
            "y_m": np.zeros(7),
            "class_id": np.zeros(7, int),
        }
    )
    props = pd.DataFrame(
        {
            "scene": ["9"] * 2,
            "token": ["a", "b"],
            "strategy": ["2N_LM"] * 2,
            "proposal": [[0, 1, 2, 3, 4, 5], [4, 5, 6, 0]],
        }
    )
    out = proposals.crop_to_densest(ref, props, 30.0)
    assert out["proposal"].tolist() == [[0, 1, 2, 3], [4, 5, 6]]
    assert proposals.crop_to_densest(ref, props, 0.0) is props  # 0: off
    ref9, q9 = scene
    real = proposals.crop_to_densest(
        ref9, proposals.simulated_coarse_proposals(ref9, q9, np.random.default_rng(1)), 30.0
    )
    xy = dict(zip(ref9["obj_idx"].astype(int), ref9[["x_m", "y_m"]].to_numpy()))
    for p in real["proposal"]:  # every kept object within 2 radii of every other
        pts = np.array([xy[o] for o in p])
        assert len(p) >= 1 and np.linalg.norm(pts[:, None] - pts[None], axis=-1).max() < 60.0


@pytest.mark.slow  # the published data (flat_root)
def test_training_proposals_regimes(scene):
    ref, q = scene
    gt = proposals.training_proposals(ref, q, "gtbb", np.random.default_rng(0))
    assert len(gt) == 1 and gt[0]["strategy"].eq("GT-BB").all()
    co = proposals.training_proposals(ref, q, "coarse", np.random.default_rng(0), copies=3, keep_gtbb=True, crop_m=30.0)
    assert len(co) == 4 and co[0]["strategy"].eq("GT-BB").all()
    assert all(p["strategy"].eq("simulated 2N_LM").all() and len(p) == len(q) for p in co[1:])
    assert co[1]["proposal"].map(list).tolist() != co[2]["proposal"].map(list).tolist()  # fresh draws
    assert len(proposals.training_proposals(ref, q, "coarse", np.random.default_rng(0), copies=2, keep_gtbb=False)) == 2
    with pytest.raises(ValueError, match="gtbb or coarse"):
        proposals.training_proposals(ref, q, "whole", np.random.default_rng(0))


@pytest.mark.slow  # the published data (flat_root)
def test_a_new_scene_is_localized_by_the_benchmark_methods_without_its_own_priors(scene):
    """Rule scene_localization's rows: the solver (no camera or scale prior from the new scene) and
    each given model, on every query, per map type x proposal; no rows for a scene without queries."""
    from flatlandia.fine import scene_localization

    ref, q = scene
    q = q.iloc[:12]
    cfg = models.FineTrainConfig(model="MLP", map_type="depth", hidden=16, heads=2, rounds=1, epochs=1)
    given = {("mlp", "depth"): (models.build_model(cfg), cfg)}
    rows = scene_localization.scene_rows(ref, q, given, ["gt", "depth"], {"camera_prior": True, "scale_prior": True})
    assert len(rows) == 2 * (2 + 1)  # proposals x (solver per map type + the depth model)
    assert (rows["queries"] == 12).all() and (rows["scene"] == "9").all()
    assert set(rows["method_slug"]) == {"solver", "mlp"} and set(
        rows.loc[rows["method_slug"] == "mlp", "map_type"]
    ) == {"depth"}
    exact = rows[(rows["method_slug"] == "solver") & (rows["map_type"] == "gt") & (rows["proposal"] == "gtbb")].iloc[0]
    assert exact["median_m"] < 0.1  # GT local maps on the oracle box: the solver is exact
    assert "| geometric solver | gt | GT-BB | 12 |" in scene_localization.render_markdown(rows, "9")
    empty = scene_localization.scene_rows(ref, q.iloc[:0], models, ["gt"], {})
    assert empty.empty and "queries" in empty.columns
    assert "No rows" in scene_localization.render_markdown(empty, "9")
