"""Rule coarse_train: training of the coarse retrieval model (:mod:`flatlandia.coarse.retrieval`).

Losses:

* **Trip**: ``mean relu(s_pos - s_neg + margin)`` over the query's matched reference objects
  (positives) paired with as many unmatched objects (negatives, redrawn every step). The paper
  draws them at random; by default half of them (``hard_negatives: 0.5``) are instead the
  unmatched nodes the model currently ranks best, the confusions N_LM / R_30 punish (at 20
  epochs: validation criterion +0.03, test R_30 success +0.04 over seeds 100 and 7;
  ``hard_negatives: 0`` is the paper's loss);
* **Sim**: weighted least squares of ``s_i`` to ``1 - S_i`` (``S`` from
  :mod:`flatlandia.coarse.target`), weights ``S_i / max_i S_i + sim_weight_floor`` (the paper's
  "weighted by normalised S"; the floor keeps dissimilar nodes in the loss), normalised per query;
* **Sim+Trip**: their sum (``trip_weight`` scales the triplet term).

Adam over batches of ``batch_size`` (query graph, reference graph) pairs, learning rate ``lr``
with a per-step cosine decay (``lr_schedule``) so that short runs (the default 20 epochs)
converge. With ``batching: scene`` (default) a batch holds queries of one scene, so a step embeds
that scene's reference graph and the batch's query graphs in one forward pass over their
disjoint union (about 4x faster per epoch than ``mixed`` batches, which embed every scene the
batch touches); each query is then compared with the nodes of its own scene. One model per loss,
trained on GT and depth local maps (each epoch draws the map type of every training query at
random from ``train_maps``). Seeded and deterministic on CPU; the best-on-validation weights are
kept (criterion: mean of the 2N_LM recall and the R_30 success over GT and depth maps, every
``eval_every`` epochs).
"""

from __future__ import annotations

import copy
import time

import numpy as np
import pandas as pd
import torch
from torch import nn

from flatlandia import checkpoints
from flatlandia.coarse import graphs, retrieval
from flatlandia.errors import InputError

# ----------------------------------------------------------------------------- losses


def sim_loss(s: torch.Tensor, S: torch.Tensor, qpos: torch.Tensor, n_queries: int, floor: float = 0.1) -> torch.Tensor:
    """Weighted regression of ``s`` to ``1 - S``; weights ``S / max_query S + floor``, mean over queries."""
    smax = torch.zeros(n_queries, dtype=S.dtype).scatter_reduce(0, qpos, S, reduce="amax", include_self=True)
    w = S / smax.clamp_min(1e-6)[qpos] + floor
    err = w * (s - (1.0 - S)) ** 2
    num = torch.zeros(n_queries, dtype=s.dtype).index_add(0, qpos, err)
    den = torch.zeros(n_queries, dtype=s.dtype).index_add(0, qpos, w)
    return (num / den.clamp_min(1e-12)).mean()


def triplet_loss(s_pos: torch.Tensor, s_neg: torch.Tensor, margin: float) -> torch.Tensor:
    """``mean relu(s_pos - s_neg + margin)`` over (positive, negative) pairs."""
    if s_pos.numel() == 0:
        return s_pos.sum()
    return torch.relu(s_pos - s_neg + margin).mean()


def draw_triplets(
    batch_samples: list[retrieval.Sample],
    sizes: list[int],
    rng: np.random.Generator,
    scores: np.ndarray | None = None,
    hard_fraction: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Pair positions (into the concatenated pair list) of positives and as many negatives: random
    unmatched nodes (the paper), of which ``hard_fraction`` (rounded, per query) are instead the
    unmatched nodes the model currently ranks best (smallest ``scores``, one per pair position)."""
    pos_all, neg_all = [], []
    start = 0
    for s, n in zip(batch_samples, sizes):
        neg_pool = s.negatives if s.negatives is not None else np.setdiff1d(np.arange(n), s.positives)
        n_pos = len(s.positives)
        if n_pos and len(neg_pool):
            n_hard = min(int(round(hard_fraction * n_pos)), len(neg_pool)) if scores is not None else 0
            hard = np.zeros(0, np.int64)
            pool = neg_pool
            if n_hard:
                order = np.argsort(scores[start + neg_pool], kind="stable")
                hard, pool = neg_pool[order[:n_hard]], neg_pool[np.sort(order[n_hard:])]
            n_rand = n_pos - n_hard
            if len(pool) >= n_rand:  # without replacement
                rand = pool[rng.permutation(len(pool))[:n_rand]]
            else:
                rand = neg_pool[rng.integers(0, len(neg_pool), n_rand)]
            neg = np.concatenate([hard, rand]).astype(np.int64)
            pos_all.append(start + s.positives)
            neg_all.append(start + neg)
        start += n
    if not pos_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(pos_all), np.concatenate(neg_all)


def batch_loss(
    model,
    ds: retrieval.Dataset,
    batch_samples: list[retrieval.Sample],
    map_types: list[str],
    cfg: retrieval.CoarseTrainConfig,
    rng: np.random.Generator,
) -> tuple[torch.Tensor, dict]:
    """The configured loss of one batch (map type per sample given); only the reference graphs of
    the batch's scenes are embedded (one fused forward pass when the batch holds one scene)."""
    scenes = {b.scene for b in batch_samples}
    qpos = np.repeat(np.arange(len(batch_samples)), [len(ds.refs[b.scene]) for b in batch_samples])
    if len(scenes) == 1:
        k = batch_samples[0].scene
        s = retrieval.fused_scores(
            model, ds.ref_graphs[k], [b.graphs[mt] for b, mt in zip(batch_samples, map_types)]
        ).reshape(-1)
    else:
        ref_emb, offsets = retrieval.reference_embeddings(model, ds, [b.scene for b in batch_samples])
        qb = graphs.batch([s.graphs[mt] for s, mt in zip(batch_samples, map_types)])
        node, qpos, row = retrieval.pair_index(ds, batch_samples, offsets)
        s = retrieval.scores(model, ref_emb, qb, node, qpos)
    parts = {}
    total = s.new_zeros(())
    if cfg.loss in ("sim", "simtrip"):
        if any(b.S is None for b in batch_samples):
            raise ValueError("the Sim loss needs the similarity table of every training query")
        S = torch.from_numpy(np.concatenate([b.S for b in batch_samples]).astype(np.float32))
        ls = sim_loss(s, S, torch.from_numpy(qpos), len(batch_samples), cfg.sim_weight_floor)
        parts["loss_sim"] = float(ls.detach())
        total = total + ls
    if cfg.loss in ("trip", "simtrip"):
        sizes = [len(ds.refs[b.scene]) for b in batch_samples]
        ip, ineg = draw_triplets(
            batch_samples, sizes, rng, s.detach().numpy() if cfg.hard_negatives else None, cfg.hard_negatives
        )
        lt = triplet_loss(s[torch.from_numpy(ip)], s[torch.from_numpy(ineg)], cfg.margin)
        parts["loss_trip"] = float(lt.detach())
        total = total + cfg.trip_weight * lt
    return total, parts


# ----------------------------------------------------------------------------- training


def validation_metric(
    model, ds: retrieval.Dataset, samples: list[retrieval.Sample], cfg: retrieval.CoarseTrainConfig
) -> float:
    """Mean of the 2N_LM recall and the R_30 success over GT and depth maps (higher is better)."""
    vals = []
    xy = [r[["x_m", "y_m"]].to_numpy(float) for r in ds.refs]
    for mt in retrieval.MAP_TYPES:
        recall, success = [], []
        for s, sc in zip(samples, retrieval.score_samples(model, ds, samples, mt)):
            order = np.argsort(sc, kind="stable")  # = propose() + proposal_metrics(), without DataFrames
            pos = np.zeros(len(sc), bool)
            pos[s.positives] = True
            recall.append(pos[order[: 2 * s.n_objects]].sum() / max(pos.sum(), 1))
            near = np.linalg.norm(xy[s.scene] - xy[s.scene][order[0]], axis=1) <= cfg.radius_m
            success.append((near & pos).sum() >= 3)
        vals += [float(np.mean(recall)), float(np.mean(success))]
    return float(np.mean(vals))


def epoch_batches(
    train_s: list[retrieval.Sample], cfg: retrieval.CoarseTrainConfig, rng: np.random.Generator
) -> list[np.ndarray]:
    """Index batches of one epoch. ``scene``: each scene's queries shuffled and cut into batches
    of at most ``batch_size``, then the batches shuffled (one reference graph per step);
    ``mixed``: one global permutation cut into batches."""
    if cfg.batching == "mixed":
        order = rng.permutation(len(train_s))
        return [order[k : k + cfg.batch_size] for k in range(0, len(order), cfg.batch_size)]
    by_scene: dict[int, list[int]] = {}
    for i, s in enumerate(train_s):
        by_scene.setdefault(s.scene, []).append(i)
    out = []
    for k in sorted(by_scene):
        idx = rng.permutation(np.asarray(by_scene[k]))
        out += [idx[j : j + cfg.batch_size] for j in range(0, len(idx), cfg.batch_size)]
    return [out[i] for i in rng.permutation(len(out))]


def train(ds: retrieval.Dataset, cfg: retrieval.CoarseTrainConfig, log=None, progress=None) -> dict:
    """Adam over batches of (query, reference) pairs; keeps the best-on-validation weights.

    Returns {'model', 'state_dict', 'config', 'history', 'best_epoch', 'best_val', 'seconds',
    'seconds_per_epoch'}.
    """
    checkpoints.set_determinism(cfg.seed)
    model = retrieval.build_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, foreach=True)
    rng = np.random.default_rng(cfg.seed)
    train_s, val_s = ds.split("train"), ds.split("val")
    if not train_s:
        raise ValueError("no training queries")
    sched = None
    if cfg.lr_schedule == "cosine":
        total = max(cfg.epochs * len(epoch_batches(train_s, cfg, np.random.default_rng(0))), 1)
        lo = cfg.lr_min_factor
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: lo + (1 - lo) * 0.5 * (1 + np.cos(np.pi * min(step, total) / total))
        )
    history, best, best_state, best_epoch = [], -np.inf, None, -1
    t0 = time.perf_counter()
    train_time = 0.0
    epochs = range(cfg.epochs)
    for ep in progress(epochs) if progress else epochs:
        te = time.perf_counter()
        model.train()
        mts = rng.choice(len(cfg.train_maps), size=len(train_s))
        tot, parts_sum, n = 0.0, {}, 0
        for idx in epoch_batches(train_s, cfg, rng):
            opt.zero_grad()
            loss, parts = batch_loss(
                model, ds, [train_s[i] for i in idx], [cfg.train_maps[mts[i]] for i in idx], cfg, rng
            )
            loss.backward()
            if cfg.grad_clip > 0:
                nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            if sched is not None:
                sched.step()
            tot += float(loss.detach()) * len(idx)
            for key, v in parts.items():
                parts_sum[key] = parts_sum.get(key, 0.0) + v * len(idx)
            n += len(idx)
        train_time += time.perf_counter() - te
        rec = {
            "epoch": ep,
            "train_loss": tot / n,
            **{k: v / n for k, v in parts_sum.items()},
            "epoch_seconds": time.perf_counter() - te,
        }
        if val_s and (ep % cfg.eval_every == 0 or ep == cfg.epochs - 1):
            rec["val_metric"] = validation_metric(model, ds, val_s, cfg)
            if rec["val_metric"] > best:
                best, best_epoch = rec["val_metric"], ep
                best_state = copy.deepcopy(model.state_dict())
        history.append(rec)
        if log is not None:
            log.info("epoch %d: %s", ep, {k: round(v, 4) for k, v in rec.items() if k != "epoch"})
    if best_state is None:
        best_state, best_epoch = copy.deepcopy(model.state_dict()), cfg.epochs - 1
    model.load_state_dict(best_state)
    model.eval()
    return {
        "model": model,
        "state_dict": best_state,
        "config": cfg.to_dict(),
        "history": history,
        "best_epoch": best_epoch,
        "best_val": float(best),
        "seconds": time.perf_counter() - t0,
        "seconds_per_epoch": train_time / max(cfg.epochs, 1),
    }


# ----------------------------------------------------------------------------- rule coarse_train


def training_dataset(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]],
    cfg: retrieval.CoarseTrainConfig,
    log=None,
    source: str = "benchmark_scenes",
) -> retrieval.Dataset:
    """The train and val queries of every scene's (reference map, queries, similarity target) as
    graphs (:func:`flatlandia.coarse.retrieval.build_dataset`). Raises :class:`InputError` (naming
    ``source``) when either split is empty."""
    ds = retrieval.build_dataset(scenes, cfg, splits=("train", "val"))
    n_train, n_val = len(ds.split("train")), len(ds.split("val"))
    if log is not None:
        log.info(
            "%s: %d train / %d val queries over %d scenes; config %s",
            retrieval.LOSSES[cfg.loss],
            n_train,
            n_val,
            len(scenes),
            cfg.to_dict(),
        )
    if not n_train or not n_val:
        raise InputError(
            source,
            f"{n_train} training and {n_val} validation queries for the coarse "
            f"{cfg.loss} model: the benchmark scenes (config benchmark_scenes) hold too few queries to train on",
        )
    return ds


def train_model(
    ds: retrieval.Dataset, cfg: retrieval.CoarseTrainConfig, log=None, progress=None
) -> tuple[dict, pd.DataFrame, dict]:
    """Rule coarse_train: one model (loss ``cfg.loss``) trained on ``ds`` (:func:`training_dataset`)
    -> (:func:`train`'s result, the training history, the history table's metadata)."""
    res = train(ds, cfg, log=log, progress=progress)
    meta = {
        "config": res["config"],
        "best_epoch": res["best_epoch"],
        "best_val": res["best_val"],
        "seconds": res["seconds"],
        "seconds_per_epoch": res["seconds_per_epoch"],
        "n_parameters": checkpoints.n_parameters(res["model"]),
    }
    return res, pd.DataFrame(res["history"]), meta
