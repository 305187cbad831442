"""Geometric solver experiments on the real test (or validation: --split val) split (reads results/ or a copy of it).

    python benchmarks/bench_fine_solver.py --root results --map depth --proposal gtbb [--every 2] [--set key=value ...]

Prints median m / deg, thresholds, gross, query time median / mean, and the per-scene medians.
One CPU thread; no training (priors from the training split, as rule fine_eval does).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia import proposals  # noqa: E402
from flatlandia.data import localmaps  # noqa: E402
from flatlandia.fine import evaluation, solver  # noqa: E402


def load(root: Path):
    scenes = []
    for s in sorted((p.name for p in root.iterdir() if p.name.isdigit()), key=int):
        r, q = root / s / "maps/reference_map.parquet", root / s / "queries/queries.parquet"
        if r.exists() and q.exists():
            scenes.append((s, pd.read_parquet(r), pd.read_parquet(q)))
    return scenes


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
    ap.add_argument("--save", default="")
    a = ap.parse_args(argv)
    geo_cfg = dict((yaml.safe_load(open(a.config)) or {}).get("fine", {}).get("geo", {}))
    for kv in a.set:
        k, v = kv.split("=", 1)
        geo_cfg[k] = yaml.safe_load(v)
    root = Path(a.root)
    scenes = load(root)
    scale_prior = None
    if a.map == "depth" and geo_cfg.get("scale_prior", True):
        scale_prior = solver.fit_priors(
            [localmaps.xy(c) for _, _, q in scenes for c in q.loc[q["split"] == "train", "gt_local_xy_m"]]
        )
    coarse = None
    if a.proposal.startswith("coarse-"):
        coarse = pd.read_parquet(root / "coarse" / a.proposal.split("-", 1)[1] / "proposals.parquet")
    parts = []
    t0 = time.perf_counter()
    for s, ref, q in scenes:
        test = q[q["split"] == a.split].iloc[:: a.every]
        if not len(test):
            continue
        if a.proposal == "gtbb":
            props = proposals.gtbb_proposals(ref, test)
        elif a.proposal == "whole":
            props = proposals.whole_map_proposals(ref, test)
        else:
            p = coarse[(coarse["scene"].astype(str) == s) & (coarse["strategy"] == geo_cfg.get("strategy", "2N_LM"))]
            props = p[p["token"].astype(str).isin(test["token"].astype(str))]
        prior, seen = evaluation.training_priors(q, geo_cfg)
        e = evaluation.evaluate_solver(
            ref, test, props, a.map, geo_cfg, prior_xy=prior, scale_prior=scale_prior, prior_seen=seen
        )
        parts.append(e)
    e = pd.concat(parts, ignore_index=True)
    s = evaluation.summarise(e)
    print(
        f"{a.split} {a.map} {a.proposal} {' '.join(a.set)}: n={s['queries']} median {s['median_m']:.2f} m / "
        f"{s['median_deg']:.2f} deg; % "
        + " / ".join(f"{s[c]:.1f}" for c in evaluation.THRESHOLD_COLUMNS)
        + f"; gross {s['gross_pct']:.1f}%; no pose {s['no_pose_pct']:.1f}%; QT median "
        f"{1000 * s['median_query_s']:.1f} ms (CPU {1000 * s['median_query_cpu_s']:.1f} ms) mean {1000 * s['mean_query_s']:.1f} ms p90 "
        f"{1000 * e['seconds'].quantile(0.9):.0f} ms; wall {time.perf_counter() - t0:.0f} s"
    )
    if a.save:
        e.to_parquet(a.save)


if __name__ == "__main__":
    main()
