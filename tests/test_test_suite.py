"""The test suite's own rules: a test that reads the published data or runs Snakemake jobs without
the slow mark stops the collection with a message saying what to add (tests/conftest.py), and no
test loads a script of benchmarks/ (hand-run only)."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import REPO, TESTS

CASES = {
    "test_data.py": """
        def test_reads_the_data(flat_root):
            assert flat_root
    """,
    "test_jobs.py": """
        from snakemake_runner import smk


        def helper(tmp_path):
            return smk(tmp_path, tmp_path, "-n")


        def test_runs_jobs(tmp_path):
            helper(tmp_path)
    """,
    "test_fast.py": """
        def test_plain():
            assert 1 + 1 == 2
    """,
}


def _collect(folder: Path) -> subprocess.CompletedProcess:
    """`pytest --collect-only` of a suite in ``folder``/tests with this suite's conftest and runner."""
    env = {**os.environ, "FLATLANDIA_ROOT": str(folder / "no-data"), "PYTHONPATH": str(REPO / "workflow")}
    args = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-p", "no:xdist"]
    return subprocess.run([*args, "tests"], cwd=folder, capture_output=True, text=True, env=env, timeout=300)


def _suite(folder: Path, marked: bool) -> Path:
    tests = folder / "tests"
    tests.mkdir(parents=True, exist_ok=True)
    for name in ("conftest.py", "snakemake_runner.py"):
        shutil.copy(TESTS / name, tests / name)
    for name, code in CASES.items():
        code = textwrap.dedent(code)
        if marked and name != "test_fast.py":
            code = "import pytest\n\npytestmark = pytest.mark.slow\n" + code
        (tests / name).write_text(code)
    return folder


def test_an_unmarked_test_of_the_data_or_of_snakemake_stops_the_collection(tmp_path):
    res = _collect(_suite(tmp_path, marked=False))
    out = res.stdout + res.stderr
    assert res.returncode != 0, out[-3000:]
    assert "2 test(s) read the published data or the photos, or run Snakemake jobs, without the slow mark" in out
    assert "tests/test_data.py::test_reads_the_data: uses the published data (fixture flat_root)" in out
    assert "tests/test_jobs.py::test_runs_jobs: runs Snakemake jobs via helper()" in out
    assert "Add the line `@pytest.mark.slow` directly above each `def test_...`" in out
    assert "test_fast.py::test_plain" not in out.split("without the slow mark")[1]


def test_marked_tests_are_collected_and_counted_in_the_slow_lane(tmp_path):
    res = _collect(_suite(tmp_path, marked=True))
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    assert "slow lane (@pytest.mark.slow): 2 of 3 tests (published data or photos 1, Snakemake jobs 1, other 0)" in out


def _loads_a_benchmark(source: str, scripts: set[str]) -> list[str]:
    """How a test module's source loads a script of benchmarks/: an import of one, or a loader call
    (importlib, runpy, sys.path) naming the folder."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.split(".")[0] in scripts | {"benchmarks"}]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in scripts | {"benchmarks"}:
            found.append(node.module)
        elif isinstance(node, ast.Call):
            name = getattr(node.func, "attr", getattr(node.func, "id", ""))
            loader = name in {"spec_from_file_location", "run_path", "import_module", "insert", "append"}
            if loader and "benchmarks" in ast.unparse(node):
                found.append(ast.unparse(node)[:120])
    return found


def test_no_test_loads_a_script_of_benchmarks():
    """benchmarks/ is hand-run only: what a test needs of it lives in the package or in tests/ (a
    test may run a benchmark as a command, as a user does, but never imports it)."""
    scripts = {p.stem for p in (REPO / "benchmarks").glob("*.py")}
    loads = {p.name: f for p in sorted(TESTS.glob("*.py")) if (f := _loads_a_benchmark(p.read_text(), scripts))}
    assert not loads, loads
    # the check on the ways a test used to load one (conftest.benchmark_module) and on a fine loader
    loaded = """
import sys
import importlib.util
import compare_tables
from bench_batch import differences
spec = importlib.util.spec_from_file_location("c", REPO / "benchmarks" / "compare_tables.py")
sys.path.insert(0, str(REPO / "benchmarks"))
other = importlib.util.spec_from_file_location("m", TINY_ROOT.parent / "make_tiny_scene.py")
"""
    found = _loads_a_benchmark(loaded, scripts)
    assert found[:2] == ["compare_tables", "bench_batch"] and len(found) == 4
    assert all("make_tiny_scene" not in f for f in found)
