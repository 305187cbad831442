"""Time the "regenerate one city's maps" use: `snakemake --cores 2 maps --config select=[CITY]` in a
fresh working directory (no results to reuse), and print wall and CPU time and what was built.

Run from the repository root:  python benchmarks/bench_maps.py [--city Paris] [--cores 2]
Target: under 2 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", default="Paris")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--flatlandia-root", default=str(REPO.parent / "shared" / "flatlandia"))
    args = ap.parse_args()
    snakemake = str(Path(sys.executable).parent / "snakemake")
    with tempfile.TemporaryDirectory() as wd:
        cmd = [
            snakemake,
            "-s",
            str(REPO / "workflow" / "Snakefile"),
            "-d",
            wd,
            "--cores",
            str(args.cores),
            "maps",
            "--config",
        ]
        cmd += [f"select=[{args.city}]", f"flatlandia_root={args.flatlandia_root}"]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        if res.returncode != 0:
            sys.exit(f"ERROR: maps for {args.city} failed (rc {res.returncode}):\n{res.stderr[-2000:]}")
        scenes = sorted(p.parent.parent.name for p in Path(wd).glob("results/*/maps/reference_map.parquet"))
        print(
            f"maps for {args.city}: {len(scenes)} scenes {scenes}; wall {wall:.0f} s, "
            f"CPU {usage.ru_utime + usage.ru_stime:.0f} s on {args.cores} cores (target: under 120 s wall)"
        )


if __name__ == "__main__":
    main()
