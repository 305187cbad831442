"""Rule fine_solver_table: the solver's rows laid out like the paper's Table 4, paper values beside."""

import json

import pandas as pd

from flatlandia import runlog, tables

#: the paper's Table 4, MLP row with GT-BB proposals (its "metres" are units x 215)
PAPER_MLP_GTBB = {"gt": (12.5, 13.0, 0.0, 0.5, 10.0, 37.0), "depth": (13.3, 12.9, 0.0, 1.9, 16.6, 36.0)}


def main(smk, log):
    rows = []
    for path in smk.input.summaries:
        s = json.loads(open(path).read())
        paper = PAPER_MLP_GTBB.get(s["map_type"]) if s["proposal"] == "gtbb" else None
        rows.append({
            "method": "bearing solver", "map_type": s["map_type"], "proposal": s["proposal"],
            "queries": int(s["queries"]), "median_m": s["median_m"], "median_deg": s["median_deg"],
            "pct_0.5m_2deg": s["pct_0.5m_2deg"], "pct_1m_5deg": s["pct_1m_5deg"],
            "pct_5m_10deg": s["pct_5m_10deg"], "pct_10m_20deg": s["pct_10m_20deg"],
            "failure_pct": s["failure_pct"], "gross_pct": s["gross_pct"], "mean_query_ms": s["mean_query_ms"],
            "median_paper_units_m": s["median_paper_units_m"],
            "paper_mlp_median_m": paper[0] if paper else float("nan"),
            "paper_mlp_median_deg": paper[1] if paper else float("nan"),
            "paper_mlp_pct_10m_20deg": paper[5] if paper else float("nan"),
        })
    df = pd.DataFrame(rows)
    tables.write_table(df, "fine_solver", smk.output.parquet, smk.output.markdown, smk.output.latex,
                       title="Fine localization, geometric bearing solver (test split; paper Table 4 layout)",
                       note="Errors in true metres; `median_paper_units_m` is the paper's convention (local-map "
                            "units x 215) for reading against its table; `paper_mlp_*`: the paper's MLP row "
                            "(GT-BB proposals), its metres being units x 215.")
    log.info("\n%s", tables.to_markdown(df))


runlog.run(main, snakemake)  # noqa: F821
