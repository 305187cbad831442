"""`flatlandia localize --batch` on a finished run, checked against its fine table, and timed.

For each solver row of RESULTS/tables/fine_localization.parquet (map type x proposal: the whole
map, GT-BB, the coarse proposals), localizes every test query of RESULTS on its scene map and that
proposal (the command's own code, flatlandia.localize.batch), scores the poses file with `flatlandia score`
(flatlandia.score) and compares the score's table row with the solver's in every non-timing column
(positions exact; headings go through degrees: floats to 1e-9). Prints the wall and CPU time of
each step, the machine and its load.

    python benchmarks/bench_batch.py --results results
    python benchmarks/bench_batch.py --results results --city results/city/20/index
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import machine  # noqa: E402

from flatlandia import paths, score  # noqa: E402
from flatlandia.fine import fine_table  # noqa: E402
from flatlandia.localize import batch  # noqa: E402
from flatlandia.report import tables

NAME_COLUMNS = {"run", "method", "method_label"}
#: positions come back bit for bit, headings through degrees (1e-13 deg)
ATOL = 1e-9


def differences(mine: pd.DataFrame, theirs: pd.DataFrame) -> list[str]:
    skip = NAME_COLUMNS | set(tables.timing_columns(mine.columns))
    return [c for c in mine.columns if c not in skip and not tables.columns_equal(mine[c], theirs[c], ATOL)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results")
    ap.add_argument("--city", help="also localize the depth queries on this city index (scored, not compared)")
    ap.add_argument("--out", help="keep the poses and scores here (default: a temporary folder)")
    args = ap.parse_args(argv)
    results = Path(args.results)
    builtin = pd.read_parquet(paths.within(results, paths.table("fine_localization")))
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_batch_"))
    print(f"machine: {machine.describe()}")
    failed = 0
    runs = [(r.map_type, r.proposal, None) for r in builtin[builtin["method"] == "solver"].itertuples()]
    runs += [("depth", "whole", args.city)] if args.city else []
    for map_type, proposal, city in runs:
        tag = f"{map_type}_{proposal}{'_city' if city else ''}"
        with machine.Clock() as c:
            b = batch.localize_batch(results, "test", map_type, city=city, progress=False, proposal=proposal)
        batch.write_poses(b, out / f"{tag}.csv")
        print(f"batch {tag}: {b.describe()}; {c.line()}")
        with machine.Clock() as c:
            scores = score.score_file(out / f"{tag}.csv", "batch", results)
            score.write_scores(scores, "batch", str(out / f"{tag}.csv"), out / tag)
        run = scores.runs[0]
        print(f"score {tag}: {run.describe()}; {c.line()}")
        if city:
            continue
        mine = fine_table.table_rows([json.loads((out / tag / run.run / "summary.json").read_text())])
        theirs = builtin[builtin["run"] == f"solver_{map_type}_{proposal}"].reset_index(drop=True)
        diff = differences(mine, theirs)
        failed += bool(diff)
        print(
            f"  vs solver_{map_type}_{proposal} of {results / 'tables' / 'fine_localization.parquet'}: "
            + ("every non-timing column equal" if not diff else f"DIFFERENT in {', '.join(diff)}")
        )
    print(f"poses and scores in {out}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
