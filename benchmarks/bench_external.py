"""Wall and CPU time of scoring an external method in the workflow (config ``external``) over a
finished run: what docs/usage.md, "Score your own method" quotes.

Copies a finished run's folder (``results/`` with its files' times kept, ``cp -a``, so nothing
built is redone) into a temporary folder, writes the solver's own whole-map depth poses as the
method ``mine``'s poses file, and runs ``snakemake --cores 2 all`` with it in the config: rule
external_eval, the fine table, the error figures, every benchmark scene's query figures and viewer,
the manifest. Prints the jobs, wall and CPU time (Snakemake and its jobs), the machine and its load.

    python benchmarks/bench_external.py --run /path/to/finished/run     # the folder holding results/
"""

from __future__ import annotations

import argparse
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import machine  # noqa: E402

from flatlandia import paths  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, required=True, help="a finished default run's folder (holding results/)")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the copy")
    args = ap.parse_args(argv)
    solver_run = paths.fine_run("solver", "depth", "whole")
    if not (args.run / solver_run).exists():
        sys.exit(f"ERROR: {args.run}: no finished run there ({solver_run})")
    folder = Path(tempfile.mkdtemp(prefix="flatlandia_external_"))
    subprocess.run(["cp", "-a", str(args.run / paths.RESULTS), str(folder / paths.RESULTS)], check=True)
    solver = pd.read_parquet(folder / solver_run)
    posed = solver[np.isfinite(solver["x"])]
    posed[["scene", "token", "x", "y", "theta_deg"]].rename(columns={"x": "x_m", "y": "y_m"}).to_csv(
        folder / "mine.csv", index=False
    )
    (folder / "ext.yaml").write_text(yaml.safe_dump({"external": [{"name": "mine", "poses": "mine.csv"}]}))
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "workflow" / "Snakefile"), "-d", str(folder)]
    cmd += ["--cores", str(args.cores), "all", "--configfile", str(folder / "ext.yaml")]
    print(f"machine: {machine.describe()}")
    print("running:", " ".join(cmd), flush=True)
    load0 = machine.load()
    t0 = time.perf_counter()
    with open(folder / "bench_external.log", "w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    load1 = machine.load()
    text = (folder / "bench_external.log").read_text()
    if rc != 0:
        sys.exit(f"ERROR: the run failed (rc {rc}); its log: {folder / 'bench_external.log'}")
    done = re.findall(r"(\d+) of (\d+) steps \(100%\) done", text)
    jobs = int(done[-1][1]) if done else 0
    per_rule = pd.Series(re.findall(r"^(?:local)?rule (\w+):", text, flags=re.M)).value_counts()
    state = (
        "quiet" if max(load0, load1) < 1.5 else "busy: other work on the machine, wall time longer than a quiet one's"
    )
    print(f"external method over a finished run: {jobs} jobs, {wall:.0f} s wall, {ru.ru_utime + ru.ru_stime:.0f} s CPU")
    print("jobs per rule: " + ", ".join(f"{r} {n}" for r, n in per_rule.items()))
    print(f"load average {load0:.2f} before, {load1:.2f} after ({state})")
    if args.keep:
        print(f"kept: {folder}")
    else:
        shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
