"""Expected time of the paper configuration (config/paper.yaml): every training it runs, measured on a
few epochs and extrapolated to its full length, per rule and for the whole run on 2 cores.

Each training job of the paper config (rules coarse_train and fine_train: model x map type x
training proposals) is built with the workflow's own entry functions (flatlandia.coarse.training,
flatlandia.fine.training) on the benchmark scenes of a finished run's results, trained for
``--epochs`` epochs on one thread, and its CPU seconds per epoch (the first epoch and the sample
building counted apart) extrapolated to the configured epochs. Validation runs every
``eval_every`` epochs in the real run; its share is measured on the short run and scaled alike.
The rest of the run (maps, evaluation, figures) is taken from a finished default run
(``--default-run``, the folder bench_default_run.py keeps): its jobs other than the trainings.

    python benchmarks/bench_paper_config.py --results /tmp/run1/results [--epochs 3] [--default-run /tmp/run1]

Prints one line per training job (s/epoch, expected minutes), the sum per rule, and the expected
wall time on 2 cores (jobs packed greedily, longest first: a lower bound), to set the SLURM
profile's runtimes (workflow/profiles/slurm/config.yaml) and the README's figure.
"""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path

import pandas as pd
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from flatlandia import config, io  # noqa: E402
from flatlandia.coarse import retrieval  # noqa: E402
from flatlandia.coarse import training as coarse_training  # noqa: E402
from flatlandia.fine import learned, training  # noqa: E402

MODELS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def paper_config() -> dict:
    """The resolved config of config/config.yaml with config/paper.yaml over it (as --configfile)."""
    import yaml

    over = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())
    return config.resolve(over)


def scenes(results: Path, with_target: bool = False) -> list[tuple]:
    out = []
    for qp in sorted(results.glob("*/queries/queries.parquet"), key=lambda p: p.parts[-3]):
        s = qp.parts[-3]
        if not s.isdigit():
            continue
        ref = pd.read_parquet(results / s / "maps/reference_map.parquet")
        q = pd.read_parquet(qp)
        if with_target:
            out.append((ref, q, pd.read_parquet(results / s / "coarse/target.parquet")))
        else:
            out.append((ref, q))
    return out


def time_fine(cfg_all: dict, results: Path, model: str, map_type: str, regime: str, epochs: int) -> dict:
    fine = cfg_all["fine"]
    p = {**fine["train"], **fine["train_overrides"][model]}
    full = int(p["epochs"])
    if regime == "coarse" and fine["coarse_training"]["epochs"]:
        full = int(fine["coarse_training"]["epochs"])
    p["epochs"] = epochs
    cfg = learned.FineTrainConfig.from_dict(p, model=MODELS[model], map_type=map_type)
    sc = scenes(results)
    c0 = cpu()
    train_s, val_s = training.training_samples(sc, cfg, regime, fine["coarse_training"])
    c1 = cpu()
    training.train(train_s, val_s, cfg)
    c2 = cpu()
    per_epoch = (c2 - c1) / epochs
    return {
        "rule": "fine_train",
        "job": f"{model}_{map_type}_{regime}",
        "epochs": full,
        "s_per_epoch": per_epoch,
        "setup_s": c1 - c0,
        "expected_min": (c1 - c0 + per_epoch * full) / 60,
    }


def time_coarse(cfg_all: dict, results: Path, loss: str, epochs: int) -> dict:
    p = dict(cfg_all["coarse"]["train"])
    full = int(p["epochs"])
    p["epochs"] = epochs
    seed = int(cfg_all["seed"]) + int(cfg_all["coarse"]["seed_offset"])  # as rules/inputs/coarse.smk
    cfg = retrieval.CoarseTrainConfig.from_dict({**p, "seed": seed, "loss": loss})
    c0 = cpu()
    ds = coarse_training.training_dataset(scenes(results, with_target=True), cfg)
    c1 = cpu()
    coarse_training.train(ds, cfg)
    c2 = cpu()
    per_epoch = (c2 - c1) / epochs
    return {
        "rule": "coarse_train",
        "job": loss,
        "epochs": full,
        "s_per_epoch": per_epoch,
        "setup_s": c1 - c0,
        "expected_min": (c1 - c0 + per_epoch * full) / 60,
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


def other_jobs_minutes(run: Path) -> float:
    """CPU minutes of a finished default run's jobs other than the trainings (its job records)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_default_run import job_times

    df = job_times(run)
    return float(df.loc[~df["rule"].isin(["fine_train", "coarse_train"]), "seconds"].sum() / 60)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--default-run", type=Path, default=None, help="a finished default run (its non-training jobs)")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    cfg_all = paper_config()
    rows = [time_coarse(cfg_all, a.results, loss, a.epochs) for loss in cfg_all["coarse"]["losses"]]
    for m, t, regime in training_jobs(cfg_all):
        rows.append(time_fine(cfg_all, a.results, m, t, regime, a.epochs))
        r = rows[-1]
        print(
            f"  {r['rule']} {r['job']}: {r['s_per_epoch']:.2f} s/epoch x {r['epochs']} -> {r['expected_min']:.0f} min",
            flush=True,
        )
    df = pd.DataFrame(rows)
    print(f"\npaper configuration (config/paper.yaml), trainings measured on {a.epochs} epochs, one thread, CPU time:")
    print(df.round({"s_per_epoch": 2, "setup_s": 1, "expected_min": 1}).to_string(index=False))
    per_rule = df.groupby("rule")["expected_min"].agg(["count", "sum", "max"])
    print("\nper rule (minutes of CPU: jobs, sum, longest job):")
    print(per_rule.round(1).to_string())
    other = other_jobs_minutes(a.default_run) if a.default_run else 0.0
    cores = [0.0, 0.0]
    for m in sorted(df["expected_min"], reverse=True):  # greedy, longest first: a lower bound
        cores[cores.index(min(cores))] += m
    wall = max(max(cores), (sum(cores) + other) / 2)
    print(
        f"\nexpected on 2 cores: about {wall / 60:.1f} h wall (trainings {df['expected_min'].sum() / 60:.1f} h of CPU"
        + (f", the rest of the run {other:.0f} min" if a.default_run else "")
        + "); longest job "
        + f"{df.loc[df['expected_min'].idxmax(), 'job']} {df['expected_min'].max() / 60:.1f} h"
    )
    io.write_parquet(df, Path("/tmp/bench_paper_config.parquet"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
