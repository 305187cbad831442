"""Seeding and model checkpoints, shared by the coarse and the fine stage so that both train,
save and reload their models the same way.

A checkpoint is ``torch.save`` of a dict holding only tensors and plain data, so that it loads
with ``torch.load(weights_only=True)``: a checkpoint someone shares cannot run code when loaded.
It holds ``format`` (:data:`FORMAT`), ``state_dict`` (the weights) and ``meta`` (a JSON text: the
resolved config, a plain dict, and the training bookkeeping: history, best epoch, validation
figure, seconds). A file needing any other object is refused; older checkpoints are rebuilt by
the workflow (delete them and rerun), there is no compatibility path.
"""

from __future__ import annotations

import json
import pickle
import re
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.files import atomic_path

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


#: Written into every checkpoint; a file without it is not one of this workflow's current checkpoints.
FORMAT = "flatlandia-checkpoint/2"

REBUILD = "delete it and rerun the workflow to rebuild it (the rule that trains the model writes a new one)"


def _plain(value):
    """JSON form of the numpy/torch scalars and arrays a training result may hold; anything else
    is a bug in the caller and stops the save (the file must hold plain data only)."""
    if isinstance(value, (np.generic, torch.Tensor)) and value.ndim == 0:
        return value.item()
    if isinstance(value, (np.ndarray, torch.Tensor)):
        return value.tolist()
    raise TypeError(f"a checkpoint keeps plain data only, not {type(value).__name__}")


def save_checkpoint(result: dict, path) -> None:
    """``torch.save`` the weights and, as JSON text, the config and bookkeeping of a training
    result, atomically (no half-written file); loadable with ``weights_only=True``."""
    meta = {k: result[k] for k in CHECKPOINT_KEYS if k in result and k != "state_dict"}
    payload = {"format": FORMAT, "state_dict": result["state_dict"], "meta": json.dumps(meta, default=_plain)}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def _unsafe_global(err: Exception) -> str:
    """What a refused checkpoint asked for, from torch's message (its 'Unsupported global' part)."""
    found = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(err))
    if found:
        return f"it asks for the Python object {found.group(1)}"
    lines = [ln.strip() for ln in str(err).splitlines() if "WeightsUnpickler error" in ln]
    return lines[0] if lines else type(err).__name__


def _read(path) -> dict:
    """The checkpoint's dict, loaded with ``weights_only=True``: tensors and plain data only; a file
    that is not a regular one or is over :data:`flatlandia.plumbing.validate.MAX_CHECKPOINT_BYTES` is refused
    before torch reads it."""
    from flatlandia.plumbing import validate

    validate.regular_file(path, validate.MAX_CHECKPOINT_BYTES, "MAX_CHECKPOINT_BYTES")
    _inflated_size(path)
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        raise InputError(
            path,
            "refused: the checkpoint needs arbitrary Python objects, not only tensors and plain data "
            f"({_unsafe_global(e)}); loading it could run code, so it is not loaded. If it is one of "
            f"this workflow's older checkpoints, {REBUILD}",
        ) from None
    except Exception as e:  # a corrupt file: torch's reader raises RuntimeError, EOFError, IndexError, ...
        raise InputError(path, f"not a readable checkpoint ({type(e).__name__}: {validate.one_line(e)})") from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise InputError(path, f"not a checkpoint of this workflow's format {FORMAT}: {REBUILD}")
    return ck


def _inflated_size(path) -> None:
    """Before ``torch.load``: the file is a zip (what ``torch.save`` writes) of at most
    MAX_CHECKPOINT_MEMBERS members whose sizes once inflated, as its directory declares them and as
    torch allocates them, total at most MAX_CHECKPOINT_BYTES: a 1.5 MB file whose tensor record is
    deflated took 2 GB. (The total bounds any compression ratio; torch's reader checks each record
    inflates to its declared size.)"""
    from flatlandia.plumbing import validate

    members = validate.zip_members(
        path, validate.MAX_CHECKPOINT_MEMBERS, "MAX_CHECKPOINT_MEMBERS", f"a checkpoint (torch.save's zip): {REBUILD}"
    )
    total = sum(i.file_size for i in members)
    if total > validate.MAX_CHECKPOINT_BYTES:
        big = max(members, key=lambda i: i.file_size)
        raise InputError(
            path,
            f"its records inflate to {total:,} bytes ({validate.shown(big.filename)}: {big.file_size:,}), over the "
            f"limit of {validate.MAX_CHECKPOINT_BYTES:,} (flatlandia.plumbing.validate.MAX_CHECKPOINT_BYTES): not loaded",
        )


def _meta(path, ck: dict) -> dict:
    """The config and bookkeeping of a checkpoint, parsed from its JSON text."""
    from flatlandia.plumbing import validate

    try:
        meta = validate.parse_json(ck["meta"], path)
    except (KeyError, TypeError) as e:
        raise InputError(path, f"the checkpoint's config is not readable JSON ({e}): {REBUILD}") from None
    except InputError as e:
        raise InputError(path, f"the checkpoint's config is not readable: {e.problem}: {REBUILD}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
        raise InputError(path, f"the checkpoint holds no config: {REBUILD}")
    return meta


def load_checkpoint(path, config_class, build_model: Callable) -> tuple[nn.Module, object]:
    """The model of a checkpoint, in eval mode, and its config (``config_class.from_dict``)."""
    ck = _read(path)
    state = ck.get("state_dict")
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(path, f"the checkpoint's weights are not a mapping of names to tensors: {REBUILD}")
    meta = _meta(path, ck)
    try:
        cfg = config_class.from_dict(meta["config"])
        with torch.device("meta"):  # shapes only, no memory: a config asking for 10 TB of weights costs nothing
            shell = build_model(cfg)
    except (TypeError, ValueError, KeyError) as e:  # ConfigError is a ValueError
        raise InputError(
            path, f"the checkpoint's config does not build a model ({_first_line(e)}): {REBUILD}"
        ) from None
    _weights_fit(path, shell.state_dict(), state)
    model = build_model(cfg)  # now known to be the size of the weights the file holds
    try:
        model.load_state_dict(state)
    except RuntimeError as e:  # missing or unexpected keys, tensors of another shape
        raise InputError(
            path, f"the weights do not fit the model its config describes ({_first_line(e)}): {REBUILD}"
        ) from None
    model.eval()
    return model, cfg


def _weights_fit(path, expected: dict, state: dict) -> None:
    """Before the model is built for real: the file's weights are exactly the tensors the config's
    model holds (names and shapes), and every one is finite (a NaN weight makes every pose NaN)."""
    want = {k: tuple(v.shape) for k, v in expected.items()}
    have = {k: tuple(v.shape) for k, v in state.items()}
    if want != have:
        missing, extra = sorted(set(want) - set(have)), sorted(set(have) - set(want))
        shape = [k for k in want if k in have and want[k] != have[k]]
        what = (
            f"missing {missing[0]}"
            if missing
            else f"unexpected {extra[0]}"
            if extra
            else f"{shape[0]} is {list(have[shape[0]])}, the model's {list(want[shape[0]])}"
        )
        raise InputError(path, f"the weights do not fit the model its config describes ({what}): {REBUILD}")
    for k, v in state.items():
        if v.is_floating_point() and not bool(torch.isfinite(v).all()):
            raise InputError(path, f"the weights {k} hold NaN or inf: {REBUILD}")


def _first_line(err: Exception) -> str:
    """The first specific line of an error (torch's load_state_dict lists every mismatch)."""
    lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
    detail = [ln for ln in lines[1:] if ln]
    return (detail[0] if detail else lines[0] if lines else type(err).__name__)[:300]


def checkpoint_info(path) -> dict:
    """The bookkeeping of a checkpoint: everything but the weights."""
    return _meta(path, _read(path))


def on_cpu(state: dict) -> dict:
    """A state dict with its tensors on the CPU (what a checkpoint stores, whatever trained it):
    the same dict when they are there already, else a copy (keeping torch's ``_metadata``)."""
    if all(t.device.type == "cpu" for t in state.values()):
        return state
    out = type(state)((k, t.detach().cpu()) for k, t in state.items())
    if hasattr(state, "_metadata"):
        out._metadata = state._metadata
    return out


def n_parameters(model: nn.Module) -> int:
    """Number of weights of a model, for the tables' model sizes."""
    return int(sum(p.numel() for p in model.parameters()))


def weights_mb(model: nn.Module) -> float:
    """Size of a model's stored tensors (parameters and buffers) in MB: the model's size, which the
    checkpoint file exceeds by its bookkeeping (whose training time varies run to run)."""
    return float(sum(t.numel() * t.element_size() for t in model.state_dict().values()) / 1e6)
