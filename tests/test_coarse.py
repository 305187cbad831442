"""Coarse map localization: graphs, similarity target, losses, proposals, metrics, training."""

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import published_scene

from flatlandia import checkpoints, geo, paper
from flatlandia.coarse import evaluation, graphs, retrieval, target, training
from flatlandia.data import localmaps
from flatlandia.report import tables

torch.set_num_threads(1)


# ----------------------------------------------------------------------------- graphs


def test_knn_edges_point_from_the_nearest_neighbours():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [10.0, 0.0]])
    e = graphs.knn_edges(xy, k=2)
    assert e.shape == (2, 8)
    into = {int(i): sorted(e[0, e[1] == i].tolist()) for i in range(4)}
    assert into == {0: [1, 2], 1: [0, 2], 2: [0, 1], 3: [1, 2]}
    assert graphs.knn_edges(xy[:2], k=7).shape == (2, 2)  # fewer nodes than k: all others


def test_full_edges_count_and_no_self_loops():
    e = graphs.full_edges(5)
    assert e.shape == (2, 20)
    assert not (e[0] == e[1]).any()
    assert len({tuple(p) for p in e.T}) == 20


def _ref_table(xy, cls, scene="0"):
    return pd.DataFrame(
        {
            "scene": scene,
            "obj_idx": np.arange(len(xy)),
            "class_id": np.asarray(cls),
            "x_m": np.asarray(xy, float)[:, 0],
            "y_m": np.asarray(xy, float)[:, 1],
        }
    )


def test_reference_graph_features_and_edges():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-100, 100, (20, 2))
    cls = rng.integers(0, 42, 20)
    cfg = graphs.GraphConfig(scale_m=50.0)
    g = graphs.reference_graph(_ref_table(xy, cls), cfg)
    assert g.x.shape == (20, 44) and g.edge_index.shape == (2, 20 * 7)
    assert torch.equal(g.x[:, :42].argmax(1), torch.as_tensor(cls))
    assert torch.allclose(g.x[:, :42].sum(1), torch.ones(20))
    assert np.allclose(g.x[:, 42:].numpy(), (xy - xy.mean(0)) / 50.0, atol=1e-5)  # centred, / scale
    s, d = g.edge_index.numpy()
    assert np.allclose(g.edge_attr[:, 0].numpy(), np.exp(-np.linalg.norm(xy[s] - xy[d], axis=1) / 50.0), atol=1e-5)


def test_query_graph_gt_and_depth_normalisation():
    gt = np.array([[10.0, 2.0], [20.0, -4.0], [30.0, 5.0]])
    cfg = graphs.GraphConfig(scale_m=50.0, depth_unit_m=25.0)
    g = graphs.query_graph(gt, [1, 2, 3], cfg)
    assert g.x.shape == (3, 44) and g.edge_index.shape == (2, 6)
    assert np.allclose(g.x[:, 42:].numpy(), (gt - gt.mean(0)) / 50.0, atol=1e-6)
    depth, _ = localmaps.normalise_depth_map(gt * 0.003)  # arbitrary published scale
    row = {"gt_local_xy_m": gt.tolist(), "depth_local_xy": depth.tolist()}
    d_m = graphs.local_map_metres(row, "depth", cfg)
    assert np.median(np.linalg.norm(d_m, axis=1)) == pytest.approx(25.0)
    with pytest.raises(ValueError):
        graphs.query_graph(gt, [1, 2], cfg)
    with pytest.raises(ValueError):
        graphs.local_map_metres(row, "lidar", cfg)


def test_batching_offsets_edges():
    g1 = graphs.query_graph(np.array([[1.0, 0], [2, 0], [3, 1]]), [0, 1, 2])
    g2 = graphs.query_graph(np.array([[1.0, 0], [2, 0], [3, 1], [5, 5]]), [0, 1, 2, 3])
    b = graphs.batch([g1, g2])
    assert b.num_graphs == 2 and b.x.shape == (7, 44) and b.edge_index.max() == 6
    assert b.batch.tolist() == [0, 0, 0, 1, 1, 1, 1]


# ----------------------------------------------------------------------------- similarity

QUERY_WORLD = np.array([[0.0, 0.0], [8.0, 1.0], [3.0, 9.0], [-6.0, 4.0]])
QUERY_CLS = np.array([1, 2, 3, 4])


CAMERA_XY = np.array([-20.0, -5.0])


def _local(world, cam=CAMERA_XY, theta=0.4):
    return geo.world_to_local(world, cam, theta)


def test_similarity_exact_copy_gives_zero_residual_and_known_ds():
    cfg = target.SimilarityConfig(radius_m=30.0, cap_m=5.0)
    far = np.array([[200.0, 200.0], [260.0, 200.0]])
    ref_xy = np.vstack([QUERY_WORLD, far])
    ref_cls = np.r_[QUERY_CLS, [1, 2]]
    idx = target.SceneIndex(ref_xy, ref_cls, cfg)
    out = target.node_similarity(idx, _local(QUERY_WORLD), QUERY_CLS)
    for i in range(4):
        assert out.loc[i, "d_p"] == pytest.approx(0.0, abs=1e-9)
        expected_ds = np.linalg.norm(QUERY_WORLD - QUERY_WORLD[i], axis=1).mean() / 30.0
        assert out.loc[i, "d_s"] == pytest.approx(expected_ds, abs=1e-9)
        assert out.loc[i, "S"] == pytest.approx(1.0 - expected_ds, abs=1e-9)
        assert out.loc[i, "n_matched"] == 4
    # isolated objects: no pair of their neighbourhood matches the query -> d_p = 1, S = 0
    assert out.loc[4, "d_p"] == 1.0 and out.loc[4, "S"] == 0.0
    assert out.loc[5, "S"] == 0.0


def test_similarity_partial_match_and_wrong_classes():
    cfg = target.SimilarityConfig(radius_m=30.0, cap_m=5.0)
    # only objects 0 and 1 of the query exist near node 0; objects 2, 3 lie 100 m away
    ref_xy = np.vstack([QUERY_WORLD[:2], QUERY_WORLD[2:] + 100.0])
    idx = target.SceneIndex(ref_xy, QUERY_CLS, cfg)
    out = target.node_similarity(idx, _local(QUERY_WORLD), QUERY_CLS)
    assert out.loc[0, "d_p"] == pytest.approx(0.5, abs=1e-9)  # (0 + 0 + 1 + 1) / 4
    assert out.loc[0, "d_s"] == pytest.approx(np.linalg.norm(QUERY_WORLD[1]) / 2 / 30.0, abs=1e-9)
    # same geometry, other classes: nothing aligns
    idx = target.SceneIndex(QUERY_WORLD, QUERY_CLS + 10, cfg)
    out = target.node_similarity(idx, _local(QUERY_WORLD), QUERY_CLS)
    assert (out["d_p"] == 1.0).all() and (out["S"] == 0.0).all()


def test_similarity_one_displaced_object_known_residual():
    """Query = the 4 objects with object 3 moved 2 m: the best alignment keeps objects 0-2 exact
    (found by the pair enumeration, no refit can do better on the mean of capped residuals by more
    than the refit's own least squares), so d_p = 2 m / 4 objects / cap 5 m = 0.1 at most."""
    cfg = target.SimilarityConfig(radius_m=30.0, cap_m=5.0)
    moved = QUERY_WORLD.copy()
    moved[3] += [2.0, 0.0]
    idx = target.SceneIndex(QUERY_WORLD, QUERY_CLS, cfg)
    out = target.node_similarity(idx, _local(moved), QUERY_CLS)
    assert (out["d_p"] <= 0.1 + 1e-9).all() and (out["d_p"] > 0.05).all()
    assert (out["n_matched"] == 4).all()  # the moved object still lands within cap_m
    # moved beyond the cap: it counts as cap_m, the other three align exactly -> d_p = 1/4 exactly
    moved[3] += [20.0, 0.0]
    out = target.node_similarity(idx, _local(moved), QUERY_CLS)
    assert np.allclose(out["d_p"], 0.25, atol=1e-9) and (out["n_matched"] == 3).all()
    for i in range(3):
        assert out.loc[i, "d_s"] == pytest.approx(np.linalg.norm(QUERY_WORLD[:3] - QUERY_WORLD[i], axis=1).mean() / 30)


def test_similarity_is_invariant_to_the_query_pose_and_bounded():
    rng = np.random.default_rng(3)
    ref_xy = rng.uniform(0, 80, (40, 2))
    ref_cls = rng.integers(0, 4, 40)
    vis = np.array([3, 7, 11, 20, 25])
    idx = target.SceneIndex(ref_xy, ref_cls)
    a = target.node_similarity(idx, _local(ref_xy[vis], np.array([0.0, 0.0]), 0.0), ref_cls[vis])
    b = target.node_similarity(idx, _local(ref_xy[vis], np.array([50.0, -30.0]), 2.5), ref_cls[vis])
    assert np.allclose(a["S"], b["S"], atol=1e-9)
    assert ((a["S"] >= 0) & (a["S"] <= 1) & (a["d_p"] >= 0) & (a["d_p"] <= 1) & (a["d_s"] >= 0) & (a["d_s"] <= 1)).all()
    # the true objects align perfectly whenever their whole query lies within their neighbourhood
    for i in vis:
        if np.linalg.norm(ref_xy[vis] - ref_xy[i], axis=1).max() <= 30.0:
            assert a.loc[i, "d_p"] == pytest.approx(0.0, abs=1e-9)


def test_scene_similarity_table_shape():
    ref = _ref_table(QUERY_WORLD, QUERY_CLS)
    q = pd.DataFrame(
        {
            "scene": ["0"],
            "token": ["t"],
            "gt_local_xy_m": [_local(QUERY_WORLD).tolist()],
            "classes": [QUERY_CLS.tolist()],
        }
    )
    t = target.scene_similarity(ref, q)
    assert list(t.columns) == ["scene", "token", "obj_idx", "S", "d_p", "d_s", "n_matched"]
    assert len(t) == 4 and t["S"].dtype == np.float32


# ----------------------------------------------------------------------------- losses


def test_triplet_loss_by_hand():
    lt = training.triplet_loss(torch.tensor([0.1, 0.5]), torch.tensor([0.3, 0.4]), margin=0.5)
    assert float(lt) == pytest.approx((0.3 + 0.6) / 2)
    assert float(training.triplet_loss(torch.tensor([0.0]), torch.tensor([2.0]), 0.5)) == 0.0


def test_sim_loss_by_hand():
    S = torch.tensor([1.0, 0.5, 0.0, 0.2])
    qpos = torch.tensor([0, 0, 0, 1])
    assert float(training.sim_loss(1.0 - S, S, qpos, 2)) == pytest.approx(0.0, abs=1e-7)
    s = torch.tensor([0.0, 0.0, 0.0, 1.0])
    # query 0: weights 1.1, 0.6, 0.1; errors 0, 0.25, 1 -> (0.15 + 0.1) / 1.8; query 1: error 0.04
    expected = ((0.6 * 0.25 + 0.1 * 1.0) / 1.8 + 0.2**2) / 2
    assert float(training.sim_loss(s, S, qpos, 2, floor=0.1)) == pytest.approx(expected, rel=1e-6)


def test_draw_triplets_picks_unmatched_negatives():
    rng = np.random.default_rng(0)
    smp = [
        retrieval.Sample(0, "a", "train", {}, np.array([1, 4]), 2, np.zeros(2), None, None),
        retrieval.Sample(0, "b", "train", {}, np.array([0, 2, 3]), 3, np.zeros(2), None, None),
    ]
    ip, ineg = training.draw_triplets(smp, [6, 6], rng)
    assert len(ip) == len(ineg) == 5
    assert set(ip[:2]) == {1, 4} and set(ip[2:]) == {6, 8, 9}
    assert not set(ineg[:2]) & {1, 4} and all(0 <= v < 6 for v in ineg[:2])
    assert not set(ineg[2:] - 6) & {0, 2, 3} and len(set(ineg[2:])) == 3


def test_draw_triplets_hard_negatives_are_the_best_ranked_unmatched():
    smp = [retrieval.Sample(0, "a", "train", {}, np.array([1, 4]), 2, np.zeros(2), None, None)]
    scores = np.array([0.9, 0.0, 0.2, 0.1, 0.5, 0.8])  # unmatched ranked 3 (0.1), 2 (0.2), 5, 0
    ip, ineg = training.draw_triplets(smp, [6], np.random.default_rng(0), scores, hard_fraction=1.0)
    assert ip.tolist() == [1, 4] and ineg.tolist() == [3, 2]
    ip, ineg = training.draw_triplets(smp, [6], np.random.default_rng(0), scores, hard_fraction=0.5)
    assert ineg[0] == 3 and ineg[1] in {0, 2, 5}  # one hard, one random among the rest
    _, ineg0 = training.draw_triplets(smp, [6], np.random.default_rng(0), scores, hard_fraction=0.0)
    _, ineg1 = training.draw_triplets(smp, [6], np.random.default_rng(0))
    assert ineg0.tolist() == ineg1.tolist()  # fraction 0: the paper's random negatives


def test_fused_scores_equal_separately_embedded_graphs():
    rng = np.random.default_rng(0)
    ref = _ref_table(rng.uniform(-60, 60, (30, 2)), rng.integers(0, 42, 30))
    cfg = retrieval.CoarseTrainConfig(seed=0)
    torch.manual_seed(0)
    model = retrieval.build_model(cfg).eval()
    rg = graphs.reference_graph(ref)
    qs = [graphs.query_graph(rng.uniform(0, 40, (m, 2)), rng.integers(0, 42, m)) for m in (3, 5, 12)]
    with torch.no_grad():
        fused = retrieval.fused_scores(model, rg, qs)
        ref_emb = retrieval.embed(model, rg)
        cached = retrieval.fused_scores(model, None, qs, ref_emb=ref_emb)
        qb = graphs.batch(qs)
        node, qpos = np.tile(np.arange(30), 3), np.repeat(np.arange(3), 30)
        sep = retrieval.scores(model, ref_emb, qb, node, qpos).reshape(3, 30)
    assert fused.shape == (3, 30)
    assert torch.allclose(fused, sep, atol=1e-5) and torch.allclose(cached, sep, atol=1e-5)


def test_cosine_schedule_and_config_checks():
    with pytest.raises(ValueError):
        retrieval.CoarseTrainConfig(lr_schedule="step")
    d = retrieval.CoarseTrainConfig().to_dict()
    assert d["lr_schedule"] in ("constant", "cosine") and 0 <= d["hard_negatives"] <= 1


# ----------------------------------------------------------------------------- proposals and metrics

XY = np.array([[0.0, 0.0], [10.0, 0.0], [25.0, 0.0], [40.0, 0.0], [0.0, 29.0], [100.0, 100.0]])
SCORE = np.array([0.5, 0.1, 0.3, 0.2, 0.9, 0.05])


def test_proposals_each_strategy():
    assert evaluation.propose(SCORE, XY, 2, "N_LM").tolist() == [1, 5]
    assert evaluation.propose(SCORE, XY, 2, "2N_LM").tolist() == [1, 2, 3, 5]
    s = SCORE.copy()
    s[5] = 1.0  # best node is 1 (x = 10 m)
    assert evaluation.propose(s, XY, 2, "R_30").tolist() == [0, 1, 2, 3]  # 40 m is exactly 30 m away
    assert evaluation.propose(s, XY, 2, "R_30", radius_m=20.0).tolist() == [0, 1, 2]
    # GT-BB: box of matched rows 1, 2 and the camera at (10, 10), enlarged 10%
    bb = evaluation.propose(SCORE, XY, 2, "GT-BB", matched_rows=[1, 2], cam_xy=[10.0, 10.0])
    assert bb.tolist() == [1, 2]
    with pytest.raises(ValueError):
        evaluation.propose(SCORE, XY, 2, "top-k")


def test_proposal_metrics():
    m = evaluation.proposal_metrics([1, 2, 3, 5], [1, 2, 3, 4])
    assert (m["precision"], m["recall"], m["success"], m["n_correct"]) == (0.75, 0.75, True, 3)
    m = evaluation.proposal_metrics([1, 9], [1, 2, 3])
    assert m["precision"] == 0.5 and m["recall"] == pytest.approx(1 / 3) and not m["success"]
    assert evaluation.proposal_metrics([], [1, 2, 3])["precision"] == 0.0


def test_summarise_and_markdown_have_the_paper_beside():
    rows = pd.DataFrame(
        {
            "scene": "0",
            "token": ["a", "b"],
            "loss": "Sim+Trip",
            "map_type": "gt",
            "strategy": "R_30",
            "proposal": [[1], [2]],
            "n_proposed": [4, 2],
            "n_correct": [3, 0],
            "precision": [0.75, 0.0],
            "recall": [1.0, 0.0],
            "success": [True, False],
        }
    )
    t = evaluation.summarise(rows)
    assert list(t.columns) == [c for c, _, _ in evaluation.TABLE_COLUMNS]
    r = t.iloc[0]
    assert (r.precision, r.recall, r.success, r.queries) == (0.375, 0.5, 0.5, 2)
    assert (r.paper_precision, r.paper_recall, r.paper_success) == paper.TABLE3[("Sim+Trip", "R_30", "gt")]
    md = evaluation.render_markdown(t)
    assert "| Sim+Trip | R_30 | 0.375 / 0.500 / 0.500 | 0.148 / 0.543 / 0.600 |" in md
    tables.check_schema(t, "coarse_localization")  # the schema-checked writer accepts it
    assert [c.name for c in tables.SCHEMAS["coarse_localization"]] == list(t.columns)


def test_config_rejects_unknown_keys_and_losses():
    with pytest.raises(ValueError):
        retrieval.CoarseTrainConfig.from_dict({"epochz": 3})
    with pytest.raises(ValueError):
        retrieval.CoarseTrainConfig(loss="contrastive")


# ----------------------------------------------------------------------------- training on real scenes

REAL_SCENES = ["0", "11", "16"]


@pytest.fixture(scope="module")
def real_data(flat_root):
    """Three scenes built from the published data: (reference map, queries, similarity table)."""
    out = []
    for s in REAL_SCENES:
        ref, q = published_scene(flat_root, s)
        out.append((ref, q, target.scene_similarity(ref, q)))
    return out


@pytest.mark.slow  # the published data (flat_root)
def test_similarity_on_real_scene_ranks_matched_objects_first(real_data):
    ref, q, sim = real_data[0]
    best = sim.loc[sim.groupby("token")["S"].idxmax()].set_index("token")["obj_idx"]
    truth = dict(zip(q["token"], q["ref_idx"]))
    hit = np.mean([int(best[t]) in set(truth[t]) for t in best.index])
    assert hit > 0.9


@pytest.mark.slow  # the published data (flat_root)
def test_training_reduces_loss_beats_random_and_is_deterministic(real_data, tmp_path):
    cfg = retrieval.CoarseTrainConfig(loss="simtrip", epochs=8, seed=0)
    ds = retrieval.build_dataset(real_data, cfg)
    assert cfg.depth_unit_m is not None and 10 < cfg.depth_unit_m < 60
    res = training.train(ds, cfg)
    hist = pd.DataFrame(res["history"])
    assert hist["train_loss"].iloc[-3:].mean() < hist["train_loss"].iloc[0]
    assert hist["loss_trip"].iloc[-1] < hist["loss_trip"].iloc[0]
    per_q = evaluation.evaluate({"Sim+Trip": (res["model"], cfg)}, ds, "test")
    t = evaluation.summarise(per_q).set_index(["loss", "strategy", "map_type"])
    for mt in ("gt", "depth"):
        for strat in ("2N_LM", "R_30"):
            assert t.loc[("Sim+Trip", strat, mt), "success"] > t.loc[("random", strat, mt), "success"]
            assert t.loc[("Sim+Trip", strat, mt), "recall"] > t.loc[("random", strat, mt), "recall"]
    assert t.loc[("-", "GT-BB", "gt"), "success"] == 1.0
    # the validation criterion (computed without DataFrames) = the per-query metrics' means
    crit = np.mean(
        [
            t.loc[("Sim+Trip", "2N_LM", mt), "recall"] if k == 0 else t.loc[("Sim+Trip", "R_30", mt), "success"]
            for mt in ("gt", "depth")
            for k in (0, 1)
        ]
    )
    assert training.validation_metric(res["model"], ds, ds.split("test"), cfg) == pytest.approx(crit, abs=1e-12)
    # checkpoint round trip, with the resolved config
    path = tmp_path / "model.pt"
    checkpoints.save_checkpoint(res, path)
    model, cfg2 = checkpoints.load_checkpoint(path, retrieval.CoarseTrainConfig, retrieval.build_model)
    assert cfg2.to_dict() == cfg.to_dict()
    test = ds.split("test")
    a = retrieval.score_samples(res["model"], ds, test, "gt")
    b = retrieval.score_samples(model, ds, test, "gt")
    assert all(np.allclose(x, y) for x, y in zip(a, b))
    # same seed, same weights (CPU)
    res2 = training.train(ds, retrieval.CoarseTrainConfig(**{**cfg.to_dict(), "epochs": 2}))
    res3 = training.train(ds, retrieval.CoarseTrainConfig(**{**cfg.to_dict(), "epochs": 2}))
    assert all(torch.equal(res2["state_dict"][k], res3["state_dict"][k]) for k in res2["state_dict"])


@pytest.mark.parametrize("loss", ["sim", "trip"])
@pytest.mark.slow  # the published data (flat_root)
def test_each_loss_trains(real_data, loss):
    cfg = retrieval.CoarseTrainConfig(loss=loss, epochs=3, seed=1, batching="mixed")
    ds = retrieval.build_dataset(real_data[:2], cfg, splits=("train", "val"))
    hist = pd.DataFrame(training.train(ds, cfg)["history"])
    key = "loss_sim" if loss == "sim" else "loss_trip"
    assert key in hist and np.isfinite(hist["train_loss"]).all()
    assert hist[key].iloc[-1] < hist[key].iloc[0]
