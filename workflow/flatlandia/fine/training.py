"""Rule fine_train: training of the learned fine-localization baselines (models in
:mod:`flatlandia.fine.models`).

The loss is ``Δo + w Δθ``: Euclidean position error in normalised units plus the absolute wrapped
angle (radians). Augmentation: a random rigid roto-translation of the region together with the
target pose (the query stays in its camera frame), and for depth maps an optional random scale of
the query. Adam on batches, seeded and deterministic on CPU; the best-on-validation weights are
kept and saved with :func:`flatlandia.checkpoints.save_checkpoint`. On a GPU (config ``device``)
the same code runs with the model and both splits moved there once (:func:`train`).
"""

from __future__ import annotations

import copy
import math
import time

import numpy as np
import pandas as pd
import torch

from flatlandia import checkpoints, proposals
from flatlandia import device as device_module
from flatlandia.fine import models
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.pyg import Data


def angle_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Absolute wrapped angle difference in radians, in [0, pi]."""
    d = a - b
    return torch.atan2(torch.sin(d), torch.cos(d)).abs()


def pose_loss(pred: torch.Tensor, target: torch.Tensor, angle_weight: float) -> torch.Tensor:
    """Mean of Δo (Euclidean position error, normalised units) + w Δθ (radians)."""
    d_o = (pred[:, :2] - target[:, :2]).norm(dim=1)
    return (d_o + angle_weight * angle_distance(pred[:, 2], target[:, 2])).mean()


def augment(batch, cfg: models.FineTrainConfig, gen: torch.Generator):
    """Random rigid roto-translation of every region (and its target pose); query maps unchanged
    but for an optional random scale of depth maps. Takes a graph batch or ``models.DenseMaps``
    (same random draws for the same samples); returns a new one."""
    n_graphs = int(batch.num_graphs)
    phi = (torch.rand(n_graphs, generator=gen) * 2 - 1) * math.radians(cfg.aug_rotate_deg)
    tr = (torch.rand(n_graphs, 2, generator=gen) * 2 - 1) * cfg.aug_translate
    c, s = torch.cos(phi), torch.sin(phi)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # (B, 2, 2)
    scale = (
        torch.exp(torch.randn(n_graphs, generator=gen) * cfg.aug_depth_scale)
        if cfg.map_type == "depth" and cfg.aug_depth_scale > 0
        else None
    )
    device = batch.y.device  # drawn on the host generator (the same draws on every device), then moved
    phi, tr, rot = (t.to(device, non_blocking=True) for t in (phi, tr, rot))
    scale = scale.to(device, non_blocking=True) if scale is not None else None
    y = batch.y.clone()
    y[:, :2] = torch.einsum("bij,bj->bi", rot, y[:, :2]) + tr
    y[:, 2] = torch.atan2(torch.sin(y[:, 2] + phi), torch.cos(y[:, 2] + phi))
    if isinstance(batch, models.DenseMaps):
        r_xy = torch.einsum("bij,blj->bli", rot, batch.r_xy) + tr[:, None]
        q_xy = batch.q_xy * scale[:, None, None] if scale is not None else batch.q_xy
        return models.DenseMaps(batch.q_cls, q_xy, batch.q_mask, batch.r_cls, r_xy, batch.r_mask, y)
    b = copy.copy(batch)
    g = batch.batch
    loc = batch.local
    moved = torch.einsum("nij,nj->ni", rot[g], loc) + tr[g]
    qloc = loc * scale[g][:, None] if scale is not None else loc
    b.local = torch.where(batch.is_q[:, None], qloc, moved)
    b.y = y
    return b


def train(
    train_samples: list[Data],
    val_samples: list[Data],
    cfg: models.FineTrainConfig,
    log=None,
    progress=None,
    init_state: dict | None = None,
    device="cpu",
) -> dict:
    """Adam on batches; the best-on-validation (median position error) weights are kept.
    ``init_state``: weights to start from (a warm start) instead of the seeded initialisation.
    ``device``: where it trains (a ``torch.device``, or the config's ``auto`` | ``cpu`` | ``cuda``):
    the model is built and seeded on the CPU, then it, the padded maps or collated graphs of both
    splits go there once; a step copies only its batch's row positions there and reads nothing
    back (the loss is summed there, read once per epoch).

    Returns {'model' (on ``device``), 'state_dict' (on the CPU), 'config', 'history', 'best_epoch',
    'best_val_median_m', 'seconds'}.
    """
    checkpoints.set_determinism(cfg.seed)
    dev = device_module.torch_device(device)
    model = models.build_model(cfg)
    if init_state is not None:
        model.load_state_dict(init_state)
    model.to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, fused=True)
    sched = (
        torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.epochs, 1), eta_min=0.01 * cfg.lr)
        if cfg.lr_schedule == "cosine"
        else None
    )
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    history, best, best_state, best_epoch = [], float("inf"), None, -1
    t0 = time.perf_counter()
    # padded (MLPs) or collated (GATs) once and moved once; a batch is a selection of rows
    split = models.dense_maps if models.is_dense(model) else models.GraphSplit
    data = split(train_samples).to(dev)
    val_data = split(val_samples).to(dev) if val_samples else val_samples
    epochs = range(cfg.epochs)
    for ep in progress(epochs) if progress else epochs:
        model.train()
        tot, n = torch.zeros((), dtype=torch.float64, device=dev), 0  # summed on the device, as float() would
        for batch in models.batches(data, cfg.batch_size, rng.permutation(len(train_samples))):
            if cfg.augment:
                batch = augment(batch, cfg, gen)
            opt.zero_grad()
            loss = pose_loss(model(batch), batch.y, cfg.angle_weight)
            loss.backward()
            opt.step()
            tot += loss.detach().double() * int(batch.num_graphs)
            n += int(batch.num_graphs)
        if sched is not None:
            sched.step()
        rec = {"epoch": ep, "train_loss": tot.item() / max(n, 1)}
        if val_samples and (ep % cfg.eval_every == 0 or ep == cfg.epochs - 1):
            e_m, e_deg = models.errors_metres(models.predict(model, val_data), val_samples, cfg)
            rec.update(val_median_m=float(np.median(e_m)), val_median_deg=float(np.median(e_deg)))
            if rec["val_median_m"] < best:
                best, best_epoch = rec["val_median_m"], ep
                best_state = copy.deepcopy(model.state_dict())
        history.append(rec)
        if log is not None:
            log.info("epoch %d: %s", ep, {k: round(v, 4) for k, v in rec.items() if k != "epoch"})
    if best_state is None:
        best_state = copy.deepcopy(model.state_dict())
    model.load_state_dict(best_state)
    return {
        "model": model,
        "state_dict": checkpoints.on_cpu(best_state),
        "config": cfg.to_dict(),
        "history": history,
        "best_epoch": best_epoch,
        "best_val_median_m": best,
        "seconds": time.perf_counter() - t0,
    }


# --------------------------------------------------------------------------- rule fine_train


def training_samples(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    cfg: models.FineTrainConfig,
    regime: str,
    coarse_training: dict,
    val_keep_gtbb: bool | None = None,
) -> tuple[list[Data], list[Data]]:
    """The (train, val) samples of every scene's (reference map, queries) with the proposals of
    ``regime`` (:func:`flatlandia.proposals.training_proposals`: ``gtbb``, or ``coarse`` with
    ``coarse_training['copies']`` simulated proposals per training query, one per validation query,
    GT-BB kept when ``keep_gtbb``, cut to ``crop_m``), drawn from one generator seeded with
    ``cfg.seed`` over the scenes in order. ``val_keep_gtbb`` overrides ``keep_gtbb`` for the
    validation split (a benchmark's experiment; the rule keeps one setting for both)."""
    rng = np.random.default_rng(cfg.seed)
    copies, crop_m = int(coarse_training["copies"]), float(coarse_training["crop_m"])
    keep = bool(coarse_training["keep_gtbb"])
    train_s: list[Data] = []
    val_s: list[Data] = []
    for ref, q in scenes:
        for split, dest, n in (("train", train_s, copies), ("val", val_s, 1)):
            qs = q[q["split"] == split]
            keep_split = keep if split == "train" or val_keep_gtbb is None else bool(val_keep_gtbb)
            for props in proposals.training_proposals(ref, qs, regime, rng, n, keep_split, crop_m):
                dest += models.samples_from_queries(ref, qs, props, cfg)[0]
    return train_s, val_s


def train_model(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    cfg: models.FineTrainConfig,
    regime: str,
    coarse_training: dict,
    init: str | None = None,
    log=None,
    progress=None,
    source: str = "benchmark_scenes",
    device="cpu",
) -> tuple[dict, pd.DataFrame, dict]:
    """Rule fine_train: one learned model on every scene's train split (validated on the val split).

    Samples from :func:`training_samples`; ``init`` is a checkpoint to start from (a warm start:
    the GT-BB-trained model of the same model and map type), else the seeded initialisation;
    ``device`` as for :func:`train`.
    Returns (:func:`train`'s result, the training history, the history table's metadata). Raises
    :class:`InputError` (naming ``source``) when the scenes hold no training or validation sample.
    """
    train_s, val_s = training_samples(scenes, cfg, regime, coarse_training)
    if log is not None:
        log.info(
            "%s on %s maps, %s proposals: %d train / %d val samples, config %s, coarse training %s",
            cfg.model,
            cfg.map_type,
            regime,
            len(train_s),
            len(val_s),
            cfg.to_dict(),
            coarse_training if regime == "coarse" else "-",
        )
    if not train_s or not val_s:
        raise InputError(
            source,
            f"{len(train_s)} training and {len(val_s)} validation samples for {cfg.model} on {cfg.map_type} maps: "
            "the benchmark scenes (config benchmark_scenes) hold too few queries to train on",
        )
    init_state = None
    if init:
        start, _ = checkpoints.load_checkpoint(init, models.FineTrainConfig, models.build_model)
        init_state = start.state_dict()
        if log is not None:
            log.info("starting from %s", init)
    res = train(train_s, val_s, cfg, log=log, progress=progress, init_state=init_state, device=device)
    meta = {
        "config": cfg.to_dict(),
        "best_epoch": res["best_epoch"],
        "train_proposals": regime,
        "coarse_training": coarse_training if regime == "coarse" else None,
        "warm_start": str(init) if init else None,
        "n_parameters": checkpoints.n_parameters(res["model"]),
        "train_seconds": res["seconds"],
    }
    return res, pd.DataFrame(res["history"]), meta
