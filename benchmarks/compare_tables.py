"""Compare the result tables of two runs: same files, same rows, same values.

    python benchmarks/compare_tables.py RESULTS_A RESULTS_B [--tolerance 0]

Every ``tables/*.parquet`` of both folders is read with pandas. Columns that measure time on the
machine (seconds, milliseconds, training minutes: flatlandia.report.tables.timing_columns) differ run to
run and are compared by presence only; every other column must be equal (exactly, or within
``--tolerance`` for floats; NaN equals NaN: flatlandia.report.tables.table_differences). Prints one line per table and exits 1 if any table differs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from flatlandia.report.tables import table_differences, timing_columns


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--tolerance", type=float, default=0.0)
    args = ap.parse_args()
    names = sorted(
        {p.name for p in (args.before / "tables").glob("*.parquet")}
        | {p.name for p in (args.after / "tables").glob("*.parquet")}
    )
    bad = 0
    for name in names:
        a, b = args.before / "tables" / name, args.after / "tables" / name
        if not (a.exists() and b.exists()):
            print(f"{name}: only in {'before' if a.exists() else 'after'}")
            bad += 1
            continue
        problems = table_differences(a, b, args.tolerance)
        skipped = timing_columns(pd.read_parquet(a).columns)
        rows = len(pd.read_parquet(a))
        print(
            f"{name}: {'equal' if not problems else '; '.join(problems)} ({rows} rows; timing columns not compared: {skipped or 'none'})"
        )
        bad += bool(problems)
    print(f"{len(names) - bad} of {len(names)} tables equal")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
