"""The README's headline table, checked against (or filled from) a finished default run's tables.

    python benchmarks/doc_figures.py --results results            # check: one line per stale cell, exit 1
    python benchmarks/doc_figures.py --results results --write    # fill the rows from the tables

Why: the README's "What you get" table quotes a default run's tables by hand, and went stale (a row
"unchanged since" an older run, figures of two runs side by side). Each row here names the table
and the row it comes from (:data:`ROWS`); a cell is the table's value rounded to one decimal. Rows
whose table is absent (the `ablations` target not run) are left as they are, and said.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

#: the README table's figure columns, in order, as the tables name them
COLUMNS = (
    "recall_1m",
    "recall_3m",
    "recall_5m",
    "recall_1deg",
    "recall_3deg",
    "recall_5deg",
    "within_5m_5deg",
    "answered_pct",
    "within_answered_pct",
)


@dataclass(frozen=True)
class Row:
    """A README row (its first cell) and where its figures come from: a table of results/tables/ and
    the values that pick its row; ``answers`` False for a method whose answers carry no probability
    (the cells read '–')."""

    label: str
    table: str
    where: tuple[tuple[str, object], ...]
    answers: bool = True


ROWS = (
    Row(
        "solver, whole map (no per-query prior)",
        "fine_localization",
        (("method", "solver"), ("proposal", "whole"), ("map_type", "depth")),
    ),
    Row(
        "solver, whole map, camera prior off",
        "ablations",
        (("method", "solver-noprior"), ("proposal", "whole"), ("map_type", "depth")),
    ),
    Row(
        "solver, GT-BB (oracle box)",
        "fine_localization",
        (("method", "solver"), ("proposal", "gtbb"), ("map_type", "depth")),
    ),
    Row(
        "MLP baseline, GT-BB (oracle box)",
        "fine_localization",
        (("method", "mlp"), ("proposal", "gtbb"), ("map_type", "depth")),
        answers=False,
    ),
    Row(
        "solver, whole map, 5 frames with odometry",
        "beyond_one_frame",
        (("map", "scene"), ("frames", 5), ("gps_sigma_m", None), ("camera_prior", "on")),
    ),
)


def _cell(v) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{float(v):.1f}"


def expected_cells(results: Path, row: Row) -> list[str] | None:
    """The row's figure cells from its table (None: the table is absent); raises ValueError when the
    table holds not exactly one such row."""
    path = results / "tables" / f"{row.table}.parquet"
    if not path.exists():
        return None
    t = pd.read_parquet(path)
    sel = pd.Series(True, index=t.index)
    for col, value in row.where:
        sel &= t[col].isna() if value is None else t[col].astype(str) == str(value)
    if int(sel.sum()) != 1:
        raise ValueError(f"{path}: {int(sel.sum())} rows match {dict(row.where)}, expected 1")
    r = t[sel].iloc[0]
    return [_cell(r[c]) if (row.answers or c not in COLUMNS[-2:]) else "–" for c in COLUMNS]


def _split(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def check(readme: str, results: Path) -> tuple[list[str], str]:
    """(one line per cell of the README that differs from its table, the README with every row
    filled from its table)."""
    lines, problems = readme.split("\n"), []
    for row in ROWS:
        found = [k for k, ln in enumerate(lines) if ln.startswith("|") and _split(ln)[0] == row.label]
        if len(found) != 1:
            problems.append(f"README: the row '{row.label}' is there {len(found)} times, expected once")
            continue
        k = found[0]
        want = expected_cells(results, row)
        if want is None:
            print(f"doc_figures: {row.table}.parquet absent: the row '{row.label}' is left as it is", file=sys.stderr)
            continue
        cells = _split(lines[k])
        have = cells[1 : 1 + len(COLUMNS)]
        for col, a, b in zip(COLUMNS, have, want):
            if a != b:
                problems.append(f"README, '{row.label}', {col}: {a}, the table says {b} ({row.table}.parquet)")
        lines[k] = "| " + " | ".join([cells[0], *want, *cells[1 + len(COLUMNS) :]]) + " |"
    return problems, "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--readme", type=Path, default=Path(__file__).resolve().parents[1] / "README.md")
    ap.add_argument("--write", action="store_true", help="fill the README's rows from the tables")
    a = ap.parse_args(argv)
    try:
        problems, filled = check(a.readme.read_text(), a.results)
    except ValueError as e:
        print(f"ERROR: {e}", file=sys.stderr)
        return 2
    if a.write:
        a.readme.write_text(filled)
        print(f"filled {len(ROWS)} rows of {a.readme} from {a.results}/tables ({len(problems)} cells changed)")
        return 0
    for p in problems:
        print(p)
    print(f"{len(problems)} stale cell(s)" if problems else "the README's table agrees with the tables")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
