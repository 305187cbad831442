"""Run the workflow's Snakefile in a scratch working directory, as a user would (:func:`smk`), and
read what it planned (:func:`job_stats`)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

SNAKEMAKE = str(Path(sys.executable).parent / "snakemake")


def smk(
    repo: Path, workdir: Path, *args: str, env: dict | None = None, snakefile: Path | None = None
) -> subprocess.CompletedProcess:
    cmd = [SNAKEMAKE, "-s", str(snakefile or repo / "workflow" / "Snakefile"), "-d", str(workdir), *args]
    # tests pass the data root through --config; the environment variable would override it
    full_env = {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"} | (env or {})
    return subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, env=full_env, timeout=900)


def job_stats(stdout: str) -> dict[str, int]:
    """Snakemake's "Job stats" table of a run or dry run (its standard output): rule -> jobs, and
    'total'. Raises ValueError naming what it got when the output holds no such table (a failed plan)."""
    if "Job stats:" not in stdout:
        raise ValueError(f"no 'Job stats' table in Snakemake's output: ...{stdout[-2000:]}")
    table = stdout.split("Job stats:", 1)[1].strip().split("\n\n", 1)[0]
    return {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)$", table, flags=re.M)}
