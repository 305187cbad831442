"""The README's headline table is checked against (or filled from) a finished run's tables by
`python benchmarks/doc_figures.py` (run as a command, as a user does): on small tables made here, a
stale cell is named and --write fills the rows in place; the README holds each of its rows once."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys

import pandas as pd
from conftest import REPO

#: the README's rows and the table row each quotes (what benchmarks/doc_figures.py reads)
ROWS = {
    "solver, whole map (no per-query prior)": (
        "fine_localization",
        {"method": "solver", "proposal": "whole", "map_type": "depth"},
    ),
    "solver, whole map, camera prior off": (
        "ablations",
        {"method": "solver-noprior", "proposal": "whole", "map_type": "depth"},
    ),
    "solver, GT-BB (oracle box)": ("fine_localization", {"method": "solver", "proposal": "gtbb", "map_type": "depth"}),
    "MLP baseline, GT-BB (oracle box)": (
        "fine_localization",
        {"method": "mlp", "proposal": "gtbb", "map_type": "depth"},
    ),
    "solver, whole map, 5 frames with odometry": (
        "beyond_one_frame",
        {"map": "scene", "frames": 5, "gps_sigma_m": math.nan, "camera_prior": "on"},
    ),
}
FIGURES = [f"recall_{k}" for k in ("1m", "3m", "5m", "1deg", "3deg", "5deg")] + ["within_5m_5deg"]


def tables(folder) -> None:
    """Each row's table with its row (figures 12.34, answers 90) and a row that must not be picked."""
    (folder / "tables").mkdir(parents=True)
    by_table: dict[str, list[dict]] = {}
    for table, where in ROWS.values():
        by_table.setdefault(table, []).append(
            {**where, **dict.fromkeys(FIGURES, 12.34), "answered_pct": 90.0, "within_answered_pct": 90.0}
        )
    for name, recs in by_table.items():
        other = {**recs[0], "method": "other", "map": "other", **dict.fromkeys(FIGURES, 55.5)}
        pd.DataFrame([*recs, other]).to_parquet(folder / "tables" / f"{name}.parquet")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / "doc_figures.py"), *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_stale_cell_is_named_and_write_fills_the_rows(tmp_path):
    tables(tmp_path)
    readme = tmp_path / "README.md"
    shutil.copy(REPO / "README.md", readme)
    before = readme.read_text()
    res = run("--results", str(tmp_path), "--readme", str(readme))
    assert res.returncode == 1 and "the table says 12.3" in res.stdout and "55.5" not in res.stdout, res.stdout
    assert run("--results", str(tmp_path), "--readme", str(readme), "--write").returncode == 0
    after = readme.read_text()
    assert after.count("\n") == before.count("\n")  # rows replaced in place, nothing else moved
    row = next(ln for ln in after.splitlines() if ln.startswith("| MLP baseline, GT-BB"))
    assert row.count("12.3") == 7 and row.count("–") == 2, row  # a method without answers: '–'
    res = run("--results", str(tmp_path), "--readme", str(readme))
    assert res.returncode == 0 and "agrees" in res.stdout, res.stdout


def test_every_row_the_checker_reads_is_in_the_readme_once():
    lines = (REPO / "README.md").read_text().splitlines()
    for label in ROWS:
        assert sum(ln.startswith(f"| {label} |") for ln in lines) == 1, label
