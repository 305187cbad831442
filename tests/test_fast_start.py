"""A localizer that starts fast: every compiled kernel of the solver is cached by numba, in a cache
folder of its own where the package folder cannot hold it (a read-only install: NUMBA_CACHE_DIR, or
numba's user cache), so only the first call ever compiles (benchmarks/bench_fast_start.py times it)."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from conftest import REPO

pytestmark = pytest.mark.slow  # it compiles every kernel once (about 15 s of CPU)

PACKAGE = REPO / "workflow" / "flatlandia"


def compiled_modules() -> set[str]:
    """The package's modules that hold cached numba kernels."""
    return {
        str(p.relative_to(PACKAGE).with_suffix("")).replace(os.sep, ".")
        for p in PACKAGE.rglob("*.py")
        if re.search(r"@njit\([^)]*cache=True", p.read_text())
    }


def test_the_warm_up_caches_every_kernel_module_in_a_cache_folder_of_its_own(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    code = "from flatlandia import solver; from flatlandia.sequences import evaluation; solver.warm_up(); evaluation.warm_up_sequence()"
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    cached = {p.name.split(".")[0] for p in (tmp_path / "numba").rglob("*.nbi")}
    # noise's kernels are inlined into their callers (inline="always"): no cache entry of their own
    solver_modules = {m.rsplit(".", 1)[-1] for m in compiled_modules() if m.startswith("solver.")} - {"noise"}
    assert solver_modules and solver_modules <= cached, (solver_modules - cached, cached)
    # a second process loads them: it writes no new index file
    before = sorted(p.stat().st_mtime_ns for p in (tmp_path / "numba").rglob("*.nbi"))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0 and before == sorted(p.stat().st_mtime_ns for p in (tmp_path / "numba").rglob("*.nbi"))
