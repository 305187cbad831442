"""Wall and CPU time of a clean default run (`snakemake --cores 2 all` from an empty folder) and its
slowest jobs.

Runs the workflow of this checkout in a fresh folder (install excluded: the packages must be
installed), then reads Snakemake's own metadata records (`.snakemake/metadata`: rule, start and end
of the job that wrote each output) for the per-job times. CPU is the user + system time of
Snakemake and every job it ran (`getrusage` of the children). With `--report DIR` it reads the
records of a finished run in DIR and runs nothing (its CPU time is then unknown).

    python benchmarks/bench_default_run.py                       # a clean default run in a temp folder
    python benchmarks/bench_default_run.py --dir /tmp/run --keep # keep the folder
    python benchmarks/bench_default_run.py --report /tmp/run     # the jobs of a finished run
    python benchmarks/bench_default_run.py -- --configfile my.yaml   # extra snakemake arguments
    python benchmarks/bench_default_run.py --target export       # another target from an empty folder

It prints the machine (CPU model, cores) and the load average before and after: a run beside other
work takes longer wall time than a quiet machine's (its CPU time much less so).
"""

from __future__ import annotations

import argparse
import base64
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 600  # the target: a clean default run within 10 minutes on 2 cores


def job_times(folder: Path) -> pd.DataFrame:
    """One row per job of the run in ``folder``: rule, an output that names it, start, end, seconds."""
    rows = {}
    for f in sorted((folder / ".snakemake" / "metadata").glob("*")):
        try:
            rec = json.loads(f.read_text())
            out = base64.b64decode(f.name.replace("@", "/")).decode()
        except (ValueError, UnicodeDecodeError):
            continue
        if rec.get("starttime") is None or rec.get("endtime") is None:
            continue
        key = (rec["rule"], rec.get("job_hash"))  # the outputs of one job share its hash
        if key not in rows or out < rows[key]["output"]:
            rows[key] = {"rule": rec["rule"], "output": out, "start": rec["starttime"], "end": rec["endtime"]}
    df = pd.DataFrame(list(rows.values()), columns=["rule", "output", "start", "end"])
    df["seconds"] = df["end"] - df["start"]
    return df.sort_values("seconds", ascending=False, ignore_index=True)


def run_measuring_own_cpu(cmd: list[str], log) -> tuple[int, float]:
    """Run ``cmd`` (Snakemake); its exit code and the CPU seconds of the Snakemake process itself
    (user + system, without its jobs), read every half second while it runs."""
    import psutil

    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
    own, watched = 0.0, psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            t = watched.cpu_times()
            own = t.user + t.system
        except psutil.Error:
            pass
        time.sleep(0.5)
    return proc.returncode, own


def report(
    df: pd.DataFrame, wall_s: float | None = None, cpu_s: float | None = None, top: int = 5, target: str = "all"
) -> None:
    span = df["end"].max() - df["start"].min() if len(df) else 0.0
    wall = wall_s if wall_s is not None else span
    cpu = f", {cpu_s / 60:.1f} min CPU" if cpu_s is not None else ""
    if target == "all":
        verdict = "within" if wall <= TARGET_S else "over"
        print(
            f"default run: {wall / 60:.1f} min wall{cpu}, {len(df)} jobs ({verdict} the {TARGET_S / 60:.0f}-minute "
            "target)"
        )
    else:
        print(f"target {target}: {wall / 60:.1f} min wall{cpu}, {len(df)} jobs")
    print(f"{top} slowest jobs (wall s, each):")
    for r in df.head(top).itertuples():
        print(f"  {r.seconds:7.1f}  {r.rule:22s} {r.output}")
    print("summed job time per rule (s, top 10):")
    per_rule = df.groupby("rule")["seconds"].agg(["sum", "count"]).sort_values("sum", ascending=False)
    for rule, r in per_rule.head(10).iterrows():
        print(f"  {r['sum']:7.1f}  {rule:22s} {int(r['count'])} job(s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dir", type=Path, help="run folder (default: a new temporary folder)")
    ap.add_argument("--keep", action="store_true", help="keep the run folder")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--report", type=Path, help="only report the jobs of a finished run in this folder")
    ap.add_argument("--target", default="all", help="the Snakemake target (default: all)")
    ap.add_argument("snakemake_args", nargs="*", help="extra snakemake arguments (after --)")
    args = ap.parse_args()
    if args.report:
        report(job_times(args.report))
        return
    folder = args.dir or Path(tempfile.mkdtemp(prefix="flatlandia_default_run_"))
    if folder.exists() and any(folder.iterdir()):
        sys.exit(f"ERROR: {folder} is not empty: a clean run needs an empty folder")
    folder.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "workflow" / "Snakefile"), "-d", str(folder)]
    cmd += ["--cores", str(args.cores), args.target, *args.snakemake_args]
    print(f"machine: {machine.describe()}")
    print("running:", " ".join(cmd), flush=True)
    load0 = machine.load()
    t0 = time.perf_counter()
    with open(folder / "bench_default_run.log", "w") as log:
        rc, own_cpu = run_measuring_own_cpu(cmd, log)
    wall = time.perf_counter() - t0
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    if rc != 0:
        sys.exit(f"ERROR: the run failed (rc {rc}); its log: {folder / 'bench_default_run.log'}")
    cpu = ru.ru_utime + ru.ru_stime
    report(job_times(folder), wall, cpu, target=args.target)
    print(
        f"the Snakemake process itself: {own_cpu:.0f} s CPU ({100 * own_cpu / max(cpu, 1e-9):.1f} % of the run's CPU; "
        "flatlandia.plumbing.scheduler keeps it low)"
    )
    load1 = machine.load()
    state = (
        "quiet" if max(load0, load1) < 1.5 else "busy: other work on the machine, wall time longer than a quiet one's"
    )
    print(f"load average {load0:.2f} before, {load1:.2f} after ({state})")
    if args.keep or args.dir:
        print(f"run folder kept: {folder}")
    else:
        shutil.rmtree(folder)


if __name__ == "__main__":
    main()
