"""Run the workflow's Snakefile in a scratch working directory, as a user would."""

from __future__ import annotations

import os
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
