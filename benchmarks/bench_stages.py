"""Stage timings from Snakemake's benchmark records (logs/benchmarks/{rule}/{wildcards}.tsv) of the last run.

Prints, per stage, the summed wall time of its jobs (what the stage costs run one job after
another; `--cores 2` overlaps them), the slowest job and the peak memory, next to the
targets. Run after `snakemake --cores 2 all`:  python benchmarks/bench_stages.py [--dir logs/benchmarks]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

STAGES = {
    "objects from class clouds (12 scenes) and Lund's SfM points (target < 120 s)": [
        "objects",
        "principal_plane",
        "reproduction_audit",
    ],
    "images branch, Lund (target < 300 s)": [
        "image_audit",
        "segment",
        "sfm",
        "classify_points",
        "gps_alignment",
    ],
    "coarse: similarity target (all scenes)": ["coarse_target"],
    "coarse: training (per loss) and evaluation": ["coarse_train", "coarse_eval"],
    "fine: training and evaluation": ["fine_train", "fine_eval"],
    "queries: recovery and local maps (published scenes and Lund)": ["recover", "queries"],
}


def records(root: Path, rule: str) -> pd.DataFrame:
    rows = []
    for f in sorted((root / rule).glob("*.tsv")):
        df = pd.read_csv(f, sep="\t")
        if len(df):
            rows.append(
                {
                    "rule": rule,
                    "job": f.stem,
                    "s": float(df["s"].iloc[-1]),
                    "max_rss_mb": float(pd.to_numeric(df["max_rss"], errors="coerce").iloc[-1]),
                }
            )
    return pd.DataFrame(rows, columns=["rule", "job", "s", "max_rss_mb"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dir", default="logs/benchmarks", type=Path)
    args = ap.parse_args()
    for stage, rules in STAGES.items():
        df = pd.concat([records(args.dir, r) for r in rules], ignore_index=True)
        if df.empty:
            print(f"{stage}: no benchmark records")
            continue
        slow = df.loc[df["s"].idxmax()]
        print(
            f"{stage}: {df['s'].sum():.1f} s summed over {len(df)} jobs; slowest {slow['rule']}/{slow['job']} "
            f"{slow['s']:.1f} s; peak RSS {df['max_rss_mb'].max():.0f} MB"
        )
        for rule, g in df.groupby("rule", sort=False):
            print(f"    {rule:22s} {g['s'].sum():8.1f} s over {len(g)} job(s)")


if __name__ == "__main__":
    main()
