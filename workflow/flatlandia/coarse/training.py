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

Adam over batches of ``batch_size`` (query graph, reference graph) pairs, learning rate ``lr`` with
a per-step cosine decay (``lr_schedule``) so that short runs (the default 20 epochs) converge. With
``batching: scene`` (default) a batch holds queries of one scene, so a step embeds that scene's
reference graph and the batch's query graphs in one forward pass over their disjoint union (several
times faster per epoch than ``mixed`` batches, which embed every scene the batch touches;
docs/measurements.md, "Code paths"); each query is then compared with the nodes of its own scene.
One model per loss, trained on GT and depth local maps (each epoch draws the map type of every
training query at random from ``train_maps``). Seeded and deterministic on CPU (config ``device``:
the same code on a GPU, the data moved there once, :func:`train`); the best-on-validation weights
are kept (criterion: mean of the 2N_LM recall and the R_30 success over GT and depth maps, every
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
from flatlandia import device as device_module
from flatlandia.coarse import graphs, retrieval
from flatlandia.plumbing.errors import InputError

# ----------------------------------------------------------------------------- losses


def sim_loss(s: torch.Tensor, S: torch.Tensor, qpos: torch.Tensor, n_queries: int, floor: float = 0.1) -> torch.Tensor:
    """Weighted regression of ``s`` to ``1 - S``; weights ``S / max_query S + floor``, mean over queries."""
    smax = torch.zeros(n_queries, dtype=S.dtype, device=S.device).scatter_reduce(
        0, qpos, S, reduce="amax", include_self=True
    )
    w = S / smax.clamp_min(1e-6)[qpos] + floor
    err = w * (s - (1.0 - S)) ** 2
    num = torch.zeros(n_queries, dtype=s.dtype, device=s.device).index_add(0, qpos, err)
    den = torch.zeros(n_queries, dtype=s.dtype, device=s.device).index_add(0, qpos, w)
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


def triplet_pairs(
    batch_samples: list[retrieval.Sample],
    sizes: list[int],
    rng: np.random.Generator,
    device,
    scores: torch.Tensor | None = None,
    hard_fraction: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The pairs of :func:`draw_triplets` as index tensors on ``device``: on the CPU drawn by it
    (the scores are readable in place), on another device by :func:`device_triplet_pairs` (the
    same pairs, nothing read back from the device)."""
    if torch.device(device).type == "cpu" and (scores is None or scores.device.type == "cpu"):
        ip, ineg = draw_triplets(
            batch_samples, sizes, rng, scores.numpy() if scores is not None else None, hard_fraction
        )
        return torch.from_numpy(ip), torch.from_numpy(ineg)
    return device_triplet_pairs(batch_samples, sizes, rng, device, scores, hard_fraction)


def device_triplet_pairs(
    batch_samples: list[retrieval.Sample],
    sizes: list[int],
    rng: np.random.Generator,
    device,
    scores: torch.Tensor | None = None,
    hard_fraction: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`draw_triplets` with the scores left where they are (a GPU): the same pairs in the same
    order from the same draws of ``rng``, as index tensors on ``device``, nothing read back.

    The host knows every random position without the scores (how many hard negatives a query
    takes and which places of the rest it draws); only which negatives rank best needs them, and
    that is one stable sort of the batch's negatives on the device (:func:`_ranked_negatives`).
    Negatives are in row order, as :func:`flatlandia.coarse.retrieval.build_dataset` makes them."""
    pos_all, neg_all = [], []
    from_rank, from_pool = [], []  # (slot, query row, rank) of hard negatives; (slot, query row, place) in the pool
    hard_rows, n_hard_of = [], []  # the queries that take hard negatives, and how many
    start, slot = 0, 0
    for s, n in zip(batch_samples, sizes):
        neg_pool = s.negatives if s.negatives is not None else np.setdiff1d(np.arange(n), s.positives)
        n_pos = len(s.positives)
        if n_pos and len(neg_pool):
            n_hard = min(int(round(hard_fraction * n_pos)), len(neg_pool)) if scores is not None else 0
            n_rand = n_pos - n_hard
            neg = np.full(n_pos, -1, np.int64)
            row = len(hard_rows)
            if n_hard:
                hard_rows.append((start, n, neg_pool))
                n_hard_of.append(n_hard)
                from_rank += [(slot + k, row, k) for k in range(n_hard)]
            if len(neg_pool) - n_hard >= n_rand:  # without replacement, as draw_triplets draws
                place = rng.permutation(len(neg_pool) - n_hard)[:n_rand]
                if n_hard:
                    from_pool += [(slot + n_hard + k, row, int(p)) for k, p in enumerate(place)]
                else:
                    neg[n_hard:] = start + neg_pool[place]
            else:
                neg[n_hard:] = start + neg_pool[rng.integers(0, len(neg_pool), n_rand)]
            pos_all.append(start + s.positives)
            neg_all.append(neg)
            slot += n_pos
        start += n
    if not pos_all:
        return torch.zeros(0, dtype=torch.long, device=device), torch.zeros(0, dtype=torch.long, device=device)
    ip, ineg = np.concatenate(pos_all).astype(np.int64), np.concatenate(neg_all)
    if not hard_rows:
        return torch.from_numpy(ip).to(device, non_blocking=True), torch.from_numpy(ineg).to(device, non_blocking=True)
    ranked, pool = _ranked_negatives(scores, hard_rows, np.asarray(n_hard_of), device)
    packed = [ip, ineg]
    for picks in (from_rank, from_pool):
        packed += list(np.asarray(picks, np.int64).reshape(-1, 3).T)
    offsets = np.array([s for s, _, _ in hard_rows], np.int64)
    packed.append(offsets)
    moved = torch.split(
        torch.from_numpy(np.concatenate(packed)).to(device, non_blocking=True), [len(a) for a in packed]
    )
    ip_t, ineg_t, r_slot, r_row, r_rank, p_slot, p_row, p_place, first = moved
    ineg_t = ineg_t.clone()
    ineg_t[r_slot] = ranked[r_row, r_rank] + first[r_row]
    ineg_t[p_slot] = pool[p_row, p_place] + first[p_row]
    return ip_t, ineg_t


def _ranked_negatives(scores: torch.Tensor, rows: list[tuple], n_hard: np.ndarray, device):
    """For the queries ``rows`` ((first pair position, nodes, negative rows) each) that take hard
    negatives: their negative rows ranked by score (ties by row, as a stable sort of the negatives
    alone ranks them) and the rest, the pool, in row order, both as (queries, width) row tensors."""
    width = max(n for _, n, _ in rows)
    q = np.repeat(np.arange(len(rows)), [len(neg) for _, _, neg in rows])
    col = np.concatenate([neg for _, _, neg in rows]).astype(np.int64)
    at = np.concatenate([start + neg for start, _, neg in rows]).astype(np.int64)
    q_t, col_t, at_t, n_hard_t = (
        torch.from_numpy(a).to(device, non_blocking=True) for a in (q, col, at, n_hard.astype(np.int64))
    )
    is_neg = torch.zeros(len(rows), width, dtype=torch.bool, device=device)
    is_neg[q_t, col_t] = True
    vals = torch.zeros(len(rows), width, dtype=scores.dtype, device=device)
    vals[q_t, col_t] = scores[at_t]
    by_score = torch.sort(vals, dim=1, stable=True).indices  # then the negatives first, keeping that order
    ranked = by_score.gather(1, torch.sort((~is_neg).gather(1, by_score).long(), dim=1, stable=True).indices)
    rank = torch.empty_like(ranked).scatter_(1, ranked, torch.arange(width, device=device).expand_as(ranked))
    in_pool = is_neg & (rank >= n_hard_t[:, None])
    pool = torch.sort((~in_pool).long(), dim=1, stable=True).indices
    return ranked, pool


def batch_loss(
    model,
    ds: retrieval.Dataset,
    batch_samples: list[retrieval.Sample],
    map_types: list[str],
    cfg: retrieval.CoarseTrainConfig,
    rng: np.random.Generator,
) -> tuple[torch.Tensor, dict]:
    """The configured loss of one batch (map type per sample given) and its parts (tensors: read
    them once an epoch, not per step); only the reference graphs of the batch's scenes are embedded
    (one fused forward pass when the batch holds one scene), on the model's device."""
    scenes = {b.scene for b in batch_samples}
    device = device_module.model_device(model)
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
        if all(b.S_t is not None for b in batch_samples):  # moved to the device once (retrieval.to_device)
            S = torch.cat([b.S_t for b in batch_samples])
        else:
            S = torch.from_numpy(np.concatenate([b.S for b in batch_samples]).astype(np.float32)).to(device)
        qpos_t = torch.from_numpy(qpos).to(device, non_blocking=True)
        ls = sim_loss(s, S, qpos_t, len(batch_samples), cfg.sim_weight_floor)
        parts["loss_sim"] = ls.detach()
        total = total + ls
    if cfg.loss in ("trip", "simtrip"):
        sizes = [len(ds.refs[b.scene]) for b in batch_samples]
        ip, ineg = triplet_pairs(
            batch_samples, sizes, rng, device, s.detach() if cfg.hard_negatives else None, cfg.hard_negatives
        )
        lt = triplet_loss(s[ip], s[ineg], cfg.margin)
        parts["loss_trip"] = lt.detach()
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


def train(ds: retrieval.Dataset, cfg: retrieval.CoarseTrainConfig, log=None, progress=None, device="cpu") -> dict:
    """Adam over batches of (query, reference) pairs; keeps the best-on-validation weights.

    ``device``: where it trains (a ``torch.device``, or the config's ``auto`` | ``cpu`` | ``cuda``):
    the model is built and seeded on the CPU, then it and the dataset's graphs and targets go there
    once (:func:`flatlandia.coarse.retrieval.to_device`); a step reads nothing back from it (the
    hard negatives are ranked there, :func:`triplet_pairs`; the losses are summed there and read
    once per epoch).

    Returns {'model' (on ``device``), 'state_dict' (on the CPU), 'config', 'history', 'best_epoch',
    'best_val', 'seconds', 'seconds_per_epoch'}.
    """
    checkpoints.set_determinism(cfg.seed)
    dev = device_module.torch_device(device)
    model = retrieval.build_model(cfg).to(dev)
    ds = retrieval.to_device(ds, dev)
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
        tot, parts_sum, n = torch.zeros((), dtype=torch.float64, device=dev), {}, 0  # as float() sums them
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
            tot += loss.detach().double() * len(idx)
            for key, v in parts.items():
                parts_sum[key] = parts_sum.get(key, 0.0) + v.double() * len(idx)
            n += len(idx)
        train_loss = tot.item() / n  # the epoch's one read from the device: it waits for the epoch's work
        part_means = {k: v.item() / n for k, v in parts_sum.items()}
        train_time += time.perf_counter() - te
        rec = {"epoch": ep, "train_loss": train_loss, **part_means, "epoch_seconds": time.perf_counter() - te}
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
        "state_dict": checkpoints.on_cpu(best_state),
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
    ds: retrieval.Dataset, cfg: retrieval.CoarseTrainConfig, log=None, progress=None, device="cpu"
) -> tuple[dict, pd.DataFrame, dict]:
    """Rule coarse_train: one model (loss ``cfg.loss``) trained on ``ds`` (:func:`training_dataset`)
    on ``device`` (as :func:`train`) -> (:func:`train`'s result, the training history, the history
    table's metadata)."""
    res = train(ds, cfg, log=log, progress=progress, device=device)
    meta = {
        "config": res["config"],
        "best_epoch": res["best_epoch"],
        "best_val": res["best_val"],
        "seconds": res["seconds"],
        "seconds_per_epoch": res["seconds_per_epoch"],
        "n_parameters": checkpoints.n_parameters(res["model"]),
    }
    return res, pd.DataFrame(res["history"]), meta
