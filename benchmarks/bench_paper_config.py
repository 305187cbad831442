"""Expected time of the paper configuration (config/paper.yaml): every training it runs, measured on a
few epochs and extrapolated to its full length, per rule and for the whole run, on 2 CPU cores or
on one GPU (``--device cuda``).

Each training job of the paper config (rules coarse_train and fine_train: model x map type x
training proposals) is built with the workflow's own entry functions (flatlandia.coarse.training,
flatlandia.fine.training) on the benchmark scenes of a finished run's results, trained for
``--epochs`` epochs on one thread, and its seconds per epoch extrapolated to the configured epochs
(the sample building counted apart). On the CPU the seconds are CPU time over every epoch; on a GPU
they are wall time over the epochs after the first (the first pays CUDA's start-up), the device
synchronised at each epoch's end. Validation runs every ``eval_every`` epochs in the real run; its
share is measured on the short run and scaled alike (on 2-3 epochs every epoch validates: an upper
bound). The rest of the run (maps, evaluation, figures) is taken from a finished default run
(``--default-run``, the folder bench_default_run.py keeps): its jobs other than the trainings.

    python benchmarks/bench_paper_config.py --results /tmp/run1/results [--epochs 3] [--default-run /tmp/run1]

A GPU machine needs only torch, torch-geometric, numpy and pandas: pack the inputs where the
workflow ran (the scenes' tables and the resolved paper config, with its schema, as one JSON file:
no Parquet, YAML or config validation needed to read it), then run there from the pack, with the
CPU's losses beside the GPU's (the same seeds, trained on the CPU in worker processes):

    python benchmarks/bench_paper_config.py --results results --pack /tmp/paper_inputs.json.gz
    python benchmarks/bench_paper_config.py --inputs /tmp/paper_inputs.json.gz --device cuda --compare-cpu

Prints one line per training job (s/epoch, expected minutes), the sum per rule, and the expected
wall time (2 cores: jobs packed greedily, longest first, a lower bound; one GPU: the jobs one after
another, and the longest job), and with ``--compare-cpu`` the largest relative difference between
the CPU's and the device's training losses of each job (stated tolerance: :data:`LOSS_TOLERANCE`).
Writes the table as CSV (``--out``). Sets the SLURM profile's runtimes (rules/inputs/*.smk) and the
docs/usage.md's and docs/measurements.md's figures.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

MODELS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
#: the largest relative difference between the CPU's and the device's training loss of an epoch
#: that counts as equal (float32 on both; the GPU sums in another order, its scatter kernels
#: atomically, and hard negatives ranked on nearly tied scores can differ)
LOSS_TOLERANCE = 0.02
#: the columns of a scene's tables a training reads (the reference map's geometry is left out)
DROP_COLUMNS = {"geometry"}


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


# ----------------------------------------------------------------------------- inputs


def paper_config() -> dict:
    """The resolved config of config/config.yaml with config/paper.yaml over it (as --configfile)."""
    import yaml

    from flatlandia import config

    over = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())
    return config.resolve(over)


def read_scenes(results: Path, only: list[str] | None = None) -> list[dict]:
    """Every published scene of a finished run's results: its reference map, queries and coarse
    similarity target (Parquet)."""
    out = []
    for qp in sorted(results.glob("*/queries/queries.parquet"), key=lambda p: p.parts[-3]):
        s = qp.parts[-3]
        if not s.isdigit() or (only and s not in only):
            continue
        tables = {"reference_map": results / s / "maps/reference_map.parquet", "queries": qp}
        tables["target"] = results / s / "coarse/target.parquet"
        out.append({"scene": s, **{k: pd.read_parquet(p) for k, p in tables.items()}})
    return out


def _plain(value):
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value] if value.dtype == object else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _table_json(df: pd.DataFrame) -> dict:
    df = df.drop(columns=[c for c in df.columns if c in DROP_COLUMNS])
    return {
        "dtypes": {c: str(t) for c, t in df.dtypes.items()},
        "columns": {c: [_plain(v) for v in df[c].to_numpy()] for c in df.columns},
    }


def _table(packed: dict) -> pd.DataFrame:
    """A table of the pack: numbers in their dtypes, list cells as numpy arrays (as Parquet gives them)."""
    cols = {}
    for c, values in packed["columns"].items():
        dtype = packed["dtypes"][c]
        if values and isinstance(values[0], list):
            cols[c] = pd.Series([np.asarray(v) for v in values], dtype=object)
        elif dtype in ("str", "string", "object"):
            cols[c] = pd.Series(values, dtype=object)
        else:
            cols[c] = pd.Series(values, dtype=dtype)
    return pd.DataFrame(cols)


def pack(results: Path, path: Path, only: list[str] | None = None) -> None:
    """Write the inputs of the benchmark (scenes, resolved paper config, schema) as one gzipped JSON file."""
    from flatlandia import config

    bundle = {
        "config": paper_config(),
        "schema": config.schema(),
        "scenes": [
            {"scene": s["scene"], **{k: _table_json(v) for k, v in s.items() if k != "scene"}}
            for s in read_scenes(results, only)
        ],
    }
    with gzip.open(path, "wt") as f:
        json.dump(bundle, f)
    print(f"packed {len(bundle['scenes'])} scenes into {path} ({path.stat().st_size / 1e6:.1f} MB)")


def unpack(path: Path) -> dict:
    with gzip.open(path, "rt") as f:
        bundle = json.load(f)
    bundle["scenes"] = [
        {"scene": s["scene"], **{k: _table(v) for k, v in s.items() if k != "scene"}} for s in bundle["scenes"]
    ]
    return bundle


def load_inputs(a) -> dict:
    """The config, schema and scenes: from a pack (``--inputs``) or a run's results."""
    if a.inputs:
        bundle = unpack(a.inputs)
        if a.scenes:
            bundle["scenes"] = [s for s in bundle["scenes"] if s["scene"] in a.scenes]
        return bundle
    from flatlandia import config

    return {"config": paper_config(), "schema": config.schema(), "scenes": read_scenes(a.results, a.scenes)}


def use_schema(schema: dict) -> None:
    """Where there is no YAML reader (a bare GPU image), the settings classes read the pack's
    schema: set before the model modules are imported, their classes are made from it."""
    try:
        import yaml  # noqa: F401
    except ImportError:
        from flatlandia import config

        config.schema = lambda: schema


# ----------------------------------------------------------------------------- timing


class EpochClock:
    """A training's ``progress`` that notes the wall clock at the start of each epoch and at the end."""

    def __init__(self):
        self.marks: list[float] = []

    def __call__(self, epochs):
        for ep in epochs:
            self.marks.append(time.perf_counter())
            yield ep
        self.marks.append(time.perf_counter())


def _per_epoch(dev: torch.device, cpu_s: float, clock: EpochClock, epochs: int) -> float:
    if dev.type == "cpu":
        return cpu_s / epochs
    walls = np.diff(clock.marks)
    return float(walls[1:].mean() if len(walls) > 1 else walls[0])


def time_fine(cfg_all: dict, scenes: list[dict], model: str, map_type: str, regime: str, epochs: int, dev) -> dict:
    from flatlandia.fine import models, training

    fine = cfg_all["fine"]
    p = {**fine["train"], **fine["train_overrides"][model]}
    full = int(p["epochs"])
    if regime == "coarse" and fine["coarse_training"]["epochs"]:
        full = int(fine["coarse_training"]["epochs"])
    p["epochs"] = epochs
    cfg = models.FineTrainConfig.from_dict(p, model=MODELS[model], map_type=map_type)
    sc = [(s["reference_map"], s["queries"]) for s in scenes]
    c0 = cpu()
    train_s, val_s = training.training_samples(sc, cfg, regime, fine["coarse_training"])
    c1 = cpu()
    clock = EpochClock()
    res = training.train(train_s, val_s, cfg, progress=clock, device=dev)
    c2 = cpu()
    per_epoch = _per_epoch(dev, c2 - c1, clock, epochs)
    return {
        "rule": "fine_train",
        "job": f"{model}_{map_type}_{regime}",
        "epochs": full,
        "s_per_epoch": per_epoch,
        "setup_s": c1 - c0,
        "expected_min": (c1 - c0 + per_epoch * full) / 60,
        "losses": [h["train_loss"] for h in res["history"]],
    }


def time_coarse(cfg_all: dict, scenes: list[dict], loss: str, epochs: int, dev) -> dict:
    from flatlandia.coarse import retrieval
    from flatlandia.coarse import training as coarse_training

    p = dict(cfg_all["coarse"]["train"])
    full = int(p["epochs"])
    p["epochs"] = epochs
    seed = int(cfg_all["seed"]) + int(cfg_all["coarse"]["seed_offset"])  # as rules/inputs/coarse.smk
    cfg = retrieval.CoarseTrainConfig.from_dict({**p, "seed": seed, "loss": loss})
    c0 = cpu()
    ds = coarse_training.training_dataset([(s["reference_map"], s["queries"], s["target"]) for s in scenes], cfg)
    c1 = cpu()
    clock = EpochClock()
    res = coarse_training.train(ds, cfg, progress=clock, device=dev)
    c2 = cpu()
    per_epoch = _per_epoch(dev, c2 - c1, clock, epochs)
    return {
        "rule": "coarse_train",
        "job": loss,
        "epochs": full,
        "s_per_epoch": per_epoch,
        "setup_s": c1 - c0,
        "expected_min": (c1 - c0 + per_epoch * full) / 60,
        "losses": [h["train_loss"] for h in res["history"]],
    }


def training_jobs(cfg_all: dict) -> list[tuple[str, str, str]]:
    """(model, map type, training proposals) of every fine_train job of the config's runs."""
    runs = cfg_all["fine"]["runs"]
    grid = [(m, t, p) for m in runs["methods"] for t in runs["map_types"] for p in runs["proposals"]]
    grid += [tuple(r.rsplit("_", 2)) for r in runs["extra"]]
    on = cfg_all["fine"]["coarse_training"]["enabled"]
    box = cfg_all["coarse"]["solver"]["fine_strategy"] == "BB"
    jobs = []
    for m, t, p in grid:
        if m not in MODELS:
            continue
        regime = "coarse" if p.startswith("coarse-") and on and not (p == "coarse-solver" and box) else "gtbb"
        if (m, t, regime) not in jobs:
            jobs.append((m, t, regime))
    return jobs


def all_jobs(cfg_all: dict, only: list[str] | None) -> list[tuple]:
    """Every training of the config: ('coarse', loss) and ('fine', model, map type, regime);
    ``only``: those whose name ('coarse_simtrip', 'fine_gat_depth_coarse') holds one of these."""
    jobs = [("coarse", loss) for loss in cfg_all["coarse"]["losses"]]
    jobs += [("fine", m, t, regime) for m, t, regime in training_jobs(cfg_all)]
    return [j for j in jobs if not only or any(o in "_".join(j) for o in only)]


def run_job(job: tuple, cfg_all: dict, scenes: list[dict], epochs: int, dev) -> dict:
    if job[0] == "coarse":
        return time_coarse(cfg_all, scenes, job[1], epochs, dev)
    return time_fine(cfg_all, scenes, *job[1:], epochs, dev)


def _cpu_reference(args) -> list[float]:
    """A job's training losses on the CPU (one thread), in a worker process."""
    job, bundle, epochs = args
    use_schema(bundle["schema"])
    torch.set_num_threads(1)
    return run_job(job, bundle["config"], bundle["scenes"], epochs, torch.device("cpu"))["losses"]


def cpu_losses(jobs: list[tuple], bundle: dict, epochs: int) -> list[list[float]]:
    """Every job's CPU losses, the jobs spread over the machine's cores (fresh worker processes:
    none inherits the GPU's state)."""
    import multiprocessing

    workers = max(1, min(len(jobs), os.cpu_count() or 1))
    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        return pool.map(_cpu_reference, [(j, bundle, epochs) for j in jobs], chunksize=1)


def relative_difference(a: list[float], b: list[float]) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-12))) if len(a) else 0.0


def other_jobs_minutes(run: Path) -> float:
    """CPU minutes of a finished default run's jobs other than the trainings (its job records)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_default_run import job_times

    df = job_times(run)
    return float(df.loc[~df["rule"].isin(["fine_train", "coarse_train"]), "seconds"].sum() / 60)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--inputs", type=Path, default=None, help="a pack written by --pack (instead of --results)")
    ap.add_argument("--pack", type=Path, default=None, help="write the inputs to this file and stop")
    ap.add_argument("--scenes", nargs="*", default=None, help="only these scene ids (a quick check)")
    ap.add_argument(
        "--only", nargs="*", default=None, help="only the jobs whose name holds one of these (a quick check)"
    )
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--device", default="cpu", help="cpu (default), cuda or auto: the config's device")
    ap.add_argument("--compare-cpu", action="store_true", help="also train on the CPU and compare the losses")
    ap.add_argument("--default-run", type=Path, default=None, help="a finished default run (its non-training jobs)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_paper_config.csv"))
    a = ap.parse_args(argv)
    if a.pack:
        pack(a.results, a.pack, a.scenes)
        return 0
    bundle = load_inputs(a)
    use_schema(bundle["schema"])
    from flatlandia import device
    from flatlandia.plumbing.errors import InputError

    torch.set_num_threads(1)
    cfg_all, scenes = bundle["config"], bundle["scenes"]
    jobs = all_jobs(cfg_all, a.only)
    try:
        dev = device.resolve(a.device)
    except InputError as e:
        print(f"ERROR: {e}", file=sys.stderr)
        return 2
    reference = cpu_losses(jobs, bundle, a.epochs) if a.compare_cpu else None
    where = device.describe(dev)
    if dev.type == "cuda":  # CUDA's start-up and cuBLAS' first call outside every job's clock
        torch.ones(8, 8, device=dev).matmul(torch.ones(8, 8, device=dev)).sum().item()
    rows = []
    for k, job in enumerate(jobs):
        r = run_job(job, cfg_all, scenes, a.epochs, dev)
        if reference is not None:
            r["cpu_losses"] = reference[k]
            r["loss_rel_diff"] = relative_difference(reference[k], r["losses"])
        rows.append(r)
        print(
            f"  {r['rule']} {r['job']}: {r['s_per_epoch']:.3f} s/epoch x {r['epochs']} -> {r['expected_min']:.1f} min"
            + (f"; losses vs CPU: {r['loss_rel_diff']:.2e}" if reference is not None else ""),
            flush=True,
        )
    df = pd.DataFrame(rows)
    clock = "CPU time, one thread" if dev.type == "cpu" else f"wall time on {where}, epochs after the first"
    print(f"\npaper configuration (config/paper.yaml), trainings measured on {a.epochs} epochs, {clock}:")
    shown = [c for c in ("rule", "job", "epochs", "s_per_epoch", "setup_s", "expected_min", "loss_rel_diff") if c in df]
    print(df[shown].round({"s_per_epoch": 3, "setup_s": 1, "expected_min": 1}).to_string(index=False))
    per_rule = df.groupby("rule")["expected_min"].agg(["count", "sum", "max"])
    print("\nper rule (minutes: jobs, sum, longest job):")
    print(per_rule.round(1).to_string())
    longest = f"longest job {df.loc[df['expected_min'].idxmax(), 'job']} {df['expected_min'].max() / 60:.2f} h"
    if dev.type == "cpu":
        other = other_jobs_minutes(a.default_run) if a.default_run else 0.0
        cores = [0.0, 0.0]
        for m in sorted(df["expected_min"], reverse=True):  # greedy, longest first: a lower bound
            cores[cores.index(min(cores))] += m
        wall = max(max(cores), (sum(cores) + other) / 2)
        print(
            f"\nexpected on 2 cores: about {wall / 60:.1f} h wall (trainings {df['expected_min'].sum() / 60:.1f} h of CPU"
            + (f", the rest of the run {other:.0f} min" if a.default_run else "")
            + f"); {longest}"
        )
    else:
        print(
            f"\nexpected on one GPU ({where}): the trainings one after another "
            f"{df['expected_min'].sum() / 60:.2f} h wall; {longest}"
        )
    if reference is not None:
        worst = float(df["loss_rel_diff"].max())
        verdict = "within" if worst <= LOSS_TOLERANCE else "OUTSIDE"
        print(
            f"CPU and {where} training losses after {a.epochs} epochs: largest relative difference {worst:.2e}, "
            f"{verdict} the tolerance {LOSS_TOLERANCE:g}"
        )
    df.drop(columns=[c for c in ("losses", "cpu_losses") if c in df]).to_csv(a.out, index=False)
    print(f"table: {a.out}")
    return 0 if reference is None or df["loss_rel_diff"].max() <= LOSS_TOLERANCE else 1


if __name__ == "__main__":
    raise SystemExit(main())
