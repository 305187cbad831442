"""The README's headline table is checked against (or filled from) a finished run's tables
(benchmarks/doc_figures.py): on small tables made here, a stale cell is named and --write fills it;
the README holds each of its rows once."""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pandas as pd
from conftest import REPO

spec = importlib.util.spec_from_file_location("doc_figures", REPO / "benchmarks" / "doc_figures.py")
doc_figures = importlib.util.module_from_spec(spec)
sys.modules["doc_figures"] = doc_figures  # its dataclasses look their module up
spec.loader.exec_module(doc_figures)


def tables(folder, value: float) -> None:
    """One table per row of the README's headline table, each cell ``value`` (answers: 90)."""
    (folder / "tables").mkdir(parents=True)
    by_table: dict[str, list[dict]] = {}
    for row in doc_figures.ROWS:
        rec = {col: v for col, v in row.where}
        rec.update({c: value for c in doc_figures.COLUMNS})
        rec.update(answered_pct=90.0, within_answered_pct=90.0)
        by_table.setdefault(row.table, []).append(rec)
    for name, recs in by_table.items():
        t = pd.DataFrame(recs)
        if "gps_sigma_m" in t:
            t["gps_sigma_m"] = t["gps_sigma_m"].astype(float)  # None -> NaN, as the table has it
        # a second row that must not be picked
        other = {k: (v + 1 if isinstance(v, (int, float)) and not np.isnan(v) else "other") for k, v in recs[0].items()}
        pd.concat([t, pd.DataFrame([other])], ignore_index=True).to_parquet(folder / "tables" / f"{name}.parquet")


def test_a_stale_cell_is_named_and_write_fills_the_rows(tmp_path):
    tables(tmp_path, 12.34)
    readme = (REPO / "README.md").read_text()
    problems, filled = doc_figures.check(readme, tmp_path)
    assert problems and all("the table says 12.3" in p or "the table says 90.0" in p for p in problems)
    again, same = doc_figures.check(filled, tmp_path)
    assert again == [] and same == filled
    row = next(ln for ln in filled.splitlines() if ln.startswith("| MLP baseline, GT-BB"))
    assert row.count("12.3") == 7 and row.count("–") == 2  # a method without answers: '–'
    assert filled.count("\n") == readme.count("\n")  # rows replaced in place, nothing else moved


def test_every_row_the_checker_reads_is_in_the_readme_once():
    lines = (REPO / "README.md").read_text().splitlines()
    for row in doc_figures.ROWS:
        assert sum(ln.startswith(f"| {row.label} |") for ln in lines) == 1, row.label
