"""A fingerprint of the trainings and evaluations of the code on the path: train every coarse and
fine model of the default config for a few epochs on a few scenes, evaluate them, and save the
losses, the weights and the predictions; ``--compare`` says whether two fingerprints are equal bit
for bit. Run it with two checkouts' code to show a change left the CPU results as they were:

    PYTHONPATH=OLD/workflow python benchmarks/training_fingerprint.py --results R --out /tmp/old.pt
    PYTHONPATH=NEW/workflow python benchmarks/training_fingerprint.py --results R --out /tmp/new.pt
    python benchmarks/training_fingerprint.py --compare /tmp/old.pt /tmp/new.pt

``R`` is a folder holding ``{scene}/maps/reference_map.parquet``, ``{scene}/queries/queries.parquet``
and ``{scene}/coarse/target.parquet`` (a finished run's ``results``). It calls the rules' entry
functions (flatlandia.coarse.training, flatlandia.coarse.evaluation, flatlandia.fine.training,
flatlandia.fine.evaluation) on one thread, with the defaults of the schema and ``--epochs`` epochs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

#: the fine trainings fingerprinted: (model, map type, training proposals, settings over the defaults)
FINE_JOBS = [
    ("MLP", "gt", "gtbb", {}),
    ("MLP", "depth", "coarse", {}),
    ("MLP", "depth", "gtbb", {"augment": True}),
    ("MLP+ATT", "depth", "gtbb", {}),
    ("GAT", "gt", "gtbb", {}),
    ("GAT", "depth", "coarse", {}),
    ("GAT", "depth", "gtbb", {"augment": True}),
    ("GAT+ATT", "depth", "gtbb", {}),
]
#: the coarse trainings: (loss, batching)
COARSE_JOBS = [("sim", "scene"), ("trip", "scene"), ("simtrip", "scene"), ("trip", "mixed")]


def _scenes(results: Path, names: list[str], target: bool) -> list[tuple]:
    out = []
    for s in names:
        row = [
            pd.read_parquet(results / s / "maps/reference_map.parquet"),
            pd.read_parquet(results / s / "queries/queries.parquet"),
        ]
        if target:
            row.append(pd.read_parquet(results / s / "coarse/target.parquet"))
        out.append(tuple(row))
    return out


def _timing_free(df: pd.DataFrame) -> dict:
    """The columns of an errors table that do not measure time, as arrays of exact texts (repr: a
    float's shortest round trip, NaN equal to NaN)."""
    return {c: df[c].map(repr).to_numpy() for c in df.columns if c not in ("seconds", "cpu_seconds")}


def fingerprint(results: Path, scenes: list[str], epochs: int) -> dict:
    from flatlandia import config
    from flatlandia.coarse import evaluation as coarse_eval
    from flatlandia.coarse import retrieval
    from flatlandia.coarse import training as coarse_training
    from flatlandia.fine import evaluation as fine_eval
    from flatlandia.fine import models
    from flatlandia.fine import training as fine_training

    torch.set_num_threads(1)
    cfg_all = config.resolve({})
    out: dict = {}
    with_target = _scenes(results, scenes, target=True)
    coarse_models = {}
    for loss, batching in COARSE_JOBS:
        t0 = time.perf_counter()
        p = {**cfg_all["coarse"]["train"], "epochs": epochs, "batching": batching}
        cfg = retrieval.CoarseTrainConfig.from_dict({**p, "seed": 100, "loss": loss})
        ds = coarse_training.training_dataset(with_target, cfg)
        res, history, _ = coarse_training.train_model(ds, cfg)
        key = f"coarse {loss} {batching}"
        out[key] = {"history": history.drop(columns=["epoch_seconds"]).to_dict("list"), "state_dict": res["state_dict"]}
        if batching == "scene":
            coarse_models[retrieval.LOSSES[loss]] = (res["model"], cfg)
        print(f"{key}: {time.perf_counter() - t0:.1f} s", flush=True)
    empty = pd.DataFrame(columns=["scene", "token", "loss", "map_type", "strategy", "proposal", "seconds"])
    ev = coarse_eval.evaluate_models(coarse_models, with_target, empty, seed=0)
    out["coarse_eval"] = {k: _timing_free(v) for k, v in ev.proposals.items()}
    plain = _scenes(results, scenes, target=False)
    fine = cfg_all["fine"]
    for model, map_type, regime, over in FINE_JOBS:
        t0 = time.perf_counter()
        slug = {"MLP": "mlp", "MLP+ATT": "mlp_att", "GAT": "gat", "GAT+ATT": "gat_att"}[model]
        p = {**fine["train"], **fine["train_overrides"][slug], "epochs": epochs, **over}
        cfg = models.FineTrainConfig.from_dict(p, model=model, map_type=map_type)
        res, history, _ = fine_training.train_model(plain, cfg, regime, dict(fine["coarse_training"]))
        key = f"fine {model} {map_type} {regime}" + "".join(f" {k}={v}" for k, v in over.items())
        errors = fine_eval.model_errors(plain, res["model"], cfg, "gtbb")
        out[key] = {"history": history.to_dict("list"), "state_dict": res["state_dict"], "errors": _timing_free(errors)}
        print(f"{key}: {time.perf_counter() - t0:.1f} s", flush=True)
    return out


def _differences(a, b, where: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where}: keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a for d in _differences(a[k], b[k], f"{where}/{k}")]
    if isinstance(a, torch.Tensor):
        return [] if isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b) else [where]
    if isinstance(a, np.ndarray):
        return [] if isinstance(b, np.ndarray) and a.shape == b.shape and (a == b).all() else [where]
    if isinstance(a, list):
        same = len(a) == len(b) and all(
            (x == y) or (isinstance(x, float) and np.isnan(x) and np.isnan(y)) for x, y in zip(a, b)
        )
        return [] if same else [where]
    return [] if a == b else [where]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--scenes", nargs="*", default=["0", "1", "2"])
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"))
    a = ap.parse_args(argv)
    if a.compare:
        fa, fb = (torch.load(p, weights_only=False) for p in a.compare)
        diff = _differences(fa, fb)
        n = sum(len(v["state_dict"]) for v in fa.values() if "state_dict" in v)
        print(f"{len(fa)} entries, {n} weight tensors: " + ("equal bit for bit" if not diff else f"{len(diff)} differ"))
        for d in diff[:40]:
            print("  differs:", d)
        return 1 if diff else 0
    import flatlandia

    print("code:", flatlandia.__file__, file=sys.stderr)
    torch.save(fingerprint(a.results, a.scenes, a.epochs), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
