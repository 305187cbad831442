"""Seeding and model checkpoints, shared by the coarse and the fine stage so that both train,
save and reload their models the same way.

A checkpoint is ``torch.save`` of a dict: the weights (``state_dict``), the resolved config
(``config``, a plain dict) and the training bookkeeping (history, best epoch, validation figure,
seconds).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from flatlandia.io import atomic_path

#: The keys of a training result that a checkpoint keeps (when present): ``best_val`` is the
#: coarse validation criterion, ``best_val_median_m`` the fine one.
CHECKPOINT_KEYS = (
    "state_dict",
    "config",
    "history",
    "best_epoch",
    "best_val",
    "best_val_median_m",
    "seconds",
    "seconds_per_epoch",
)


def set_determinism(seed: int) -> None:
    """Seed torch and numpy and ask torch for deterministic kernels: a training run repeats exactly on CPU."""
    torch.manual_seed(seed)
    np.random.seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)


def save_checkpoint(result: dict, path) -> None:
    """``torch.save`` the checkpoint keys of a training result, atomically (no half-written file)."""
    with atomic_path(path) as tmp:
        torch.save({k: result[k] for k in CHECKPOINT_KEYS if k in result}, tmp)


def load_checkpoint(path, config_class, build_model: Callable) -> tuple[nn.Module, object]:
    """The model of a checkpoint, in eval mode, and its config (``config_class.from_dict``)."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = config_class.from_dict(ck["config"])
    model = build_model(cfg)
    model.load_state_dict(ck["state_dict"])
    model.eval()
    return model, cfg


def checkpoint_info(path) -> dict:
    """The bookkeeping of a checkpoint: everything but the weights."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    return {k: v for k, v in ck.items() if k != "state_dict"}


def n_parameters(model: nn.Module) -> int:
    """Number of weights of a model, for the tables' model sizes."""
    return int(sum(p.numel() for p in model.parameters()))
