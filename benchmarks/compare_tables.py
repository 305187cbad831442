"""Compare the result tables of two runs: same files, same rows, same values.

    python benchmarks/compare_tables.py RESULTS_A RESULTS_B [--tolerance 0]

Every ``tables/*.parquet`` of both folders is read with pandas. Columns that measure time on the
machine (seconds, milliseconds, training minutes) differ run to run and are compared by presence
only; every other column must be equal (exactly, or within ``--tolerance`` for floats; NaN equals
NaN). Prints one line per table and exits 1 if any table differs.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

#: columns whose values are wall or CPU times of this run, not results
TIMING = re.compile(r"(^|_)(s|ms|sec|seconds|time|minutes|min)(_|$)|query_ms|train_s|qt_", re.IGNORECASE)


def timing_columns(columns) -> list[str]:
    return [c for c in columns if TIMING.search(str(c)) and not str(c).startswith("paper_")]


def _equal(a: pd.Series, b: pd.Series, tolerance: float) -> bool:
    if a.dtype.kind in "fc" and b.dtype.kind in "fc":
        return bool(np.allclose(a.to_numpy(float), b.to_numpy(float), rtol=0, atol=tolerance, equal_nan=True))
    return a.astype(str).tolist() == b.astype(str).tolist()


def compare(a: Path, b: Path, tolerance: float) -> list[str]:
    """Differences between table ``a`` and table ``b`` (empty when they agree)."""
    ta, tb = pd.read_parquet(a), pd.read_parquet(b)
    if list(ta.columns) != list(tb.columns):
        return [f"columns differ: {sorted(set(ta.columns) ^ set(tb.columns))}"]
    if len(ta) != len(tb):
        return [f"{len(ta)} rows vs {len(tb)}"]
    skip = set(timing_columns(ta.columns))
    return [f"column {c!r} differs" for c in ta.columns if c not in skip and not _equal(ta[c], tb[c], tolerance)]


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
        problems = compare(a, b, args.tolerance)
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
