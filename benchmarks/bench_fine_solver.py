"""Geometric solver experiments on the real test (or validation: --split val) split (reads results/ or a copy of it).

    python benchmarks/bench_fine_solver.py --root results --map depth --proposal gtbb [--every 2] [--set key=value ...]
    python benchmarks/bench_fine_solver.py --root results --map depth --proposal whole --verify-seeds 0 1 2

Prints median m / deg, the recalls at 1/3/5 m and 1/3/5 deg, % within (5 m, 5 deg) and the paper's
thresholds, gross and no-pose shares, and the query time (CPU of the process and wall, median and
p90). One CPU thread; priors and, on depth maps, the verifier from the training split, as rule
fine_eval has them; ``--verify-seeds``: one run per verifier learned from a random share of the
training queries (the spread over seeds).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia import solver  # noqa: E402
from flatlandia.benchmark import metrics, solver_runs  # noqa: E402


def load(root: Path):
    scenes = []
    for s in sorted((p.name for p in root.iterdir() if p.name.isdigit()), key=int):
        r, q = root / s / "maps/reference_map.parquet", root / s / "queries/queries.parquet"
        if r.exists() and q.exists():
            scenes.append((s, pd.read_parquet(r), pd.read_parquet(q)))
    return scenes


def describe(e: pd.DataFrame) -> str:
    """One line: median errors, recalls at 1/3/5 m and 1/3/5 deg, % within (5 m, 5 deg) and the
    paper's thresholds, gross and no-pose shares, query time (CPU of the process and wall) median / p90."""
    s = metrics.summarise(e)
    em, ed = e["error_m"].to_numpy(float), e["error_deg"].to_numpy(float)
    ms = 1000 * e[["cpu_seconds", "seconds"]].quantile([0.5, 0.9])
    return (
        f"n={s['queries']} median {s['median_m']:.2f} m / {s['median_deg']:.2f} deg; "
        f"% within {'/'.join(f'{m:g}' for m in metrics.RECALL_M)} m "
        + " / ".join(f"{s[c]:.1f}" for c in metrics.RECALL_COLUMNS[: len(metrics.RECALL_M)])
        + f", {'/'.join(f'{d:g}' for d in metrics.RECALL_DEG)} deg "
        + " / ".join(f"{s[c]:.1f}" for c in metrics.RECALL_COLUMNS[len(metrics.RECALL_M) :])
        + f", (5 m, 5 deg) {100 * ((em < 5) & (ed < 5)).mean():.1f}; paper thresholds "
        + " / ".join(f"{s[c]:.1f}" for c in metrics.THRESHOLD_COLUMNS)
        + f"; gross {s['gross_pct']:.1f}%; no pose {s['no_pose_pct']:.1f}%; query CPU median "
        f"{ms.loc[0.5, 'cpu_seconds']:.1f} ms p90 {ms.loc[0.9, 'cpu_seconds']:.1f} ms (wall "
        f"{ms.loc[0.5, 'seconds']:.1f} / {ms.loc[0.9, 'seconds']:.1f} ms)"
    )


def solver_errors(
    scenes,
    split: str,
    map_type: str,
    proposal: str,
    solver_settings: dict,
    every: int = 1,
    root: Path | None = None,
    **fit,
) -> pd.DataFrame:
    """Per-query errors of the solver as rule fine_eval computes them (its entry function, with the
    priors rule solver_priors learns for depth maps); ``fit``: ``fraction`` and ``rng`` of the
    verifier's examples (``verify_fit.fit_verifier``)."""
    learned = None
    if map_type == "depth":
        c0 = time.process_time()
        region = proposal if proposal in ("whole", "gtbb") else None
        learned = solver.learned_priors.fit([(ref, q) for _, ref, q in scenes], solver_settings, region, **fit)
        if learned.verifier is not None:
            print(f"verifier learned from the training split in {time.process_time() - c0:.0f} s CPU")
    coarse = None
    if proposal.startswith("coarse-"):
        coarse = pd.read_parquet(root / "coarse" / proposal.split("-", 1)[1] / "proposals.parquet")
    solver_settings = dict(solver_settings)
    strategy = solver_settings.pop("strategy", "2N_LM")
    return solver_runs.solver_errors(
        [(ref, q) for _, ref, q in scenes], map_type, proposal, solver_settings, learned, coarse, strategy, split, every
    )


def solver_config(path: str, overrides: list[str]) -> dict:
    """The ``solver`` section of a config file with ``key=value`` overrides (YAML values)."""
    solver_settings = dict((yaml.safe_load(open(path)) or {}).get("solver", {}))
    for kv in overrides:
        k, v = kv.split("=", 1)
        solver_settings[k] = yaml.safe_load(v)
    return solver_settings


def main(argv=None):
    import torch

    torch.set_num_threads(1)
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default="results")
    ap.add_argument("--map", default="depth")
    ap.add_argument("--proposal", default="gtbb")
    ap.add_argument("--every", type=int, default=1, help="every n-th query (subset)")
    ap.add_argument("--split", default="test", help="queries to evaluate: test, or val to tune without the test split")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--set", nargs="*", default=[], help="solver overrides key=value (YAML values)")
    ap.add_argument("--verify-seeds", type=int, nargs="*", default=[], help="verifiers from random training subsets")
    ap.add_argument("--verify-fraction", type=float, default=0.8, help="share of training queries per seed")
    ap.add_argument("--save", default="")
    a = ap.parse_args(argv)
    solver_settings = solver_config(a.config, a.set)
    root = Path(a.root)
    scenes = load(root)
    runs = (
        {"": {}}
        if not a.verify_seeds
        else {
            f" verifier seed {seed}": {"fraction": a.verify_fraction, "rng": np.random.default_rng(seed)}
            for seed in a.verify_seeds
        }
    )
    for label, fit in runs.items():
        t0 = time.perf_counter()
        e = solver_errors(scenes, a.split, a.map, a.proposal, solver_settings, a.every, root, **fit)
        print(
            f"{a.split} {a.map} {a.proposal} {' '.join(a.set)}{label}: {describe(e)}; wall {time.perf_counter() - t0:.0f} s"
        )
    if a.save:
        e.to_parquet(a.save)


if __name__ == "__main__":
    main()
