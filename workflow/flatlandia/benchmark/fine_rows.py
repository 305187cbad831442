"""The ``fine_localization`` table's rows (schema in :data:`flatlandia.report.tables.SCHEMAS`): one per
run summary, the paper's row of the same method, map type and proposal beside it. Why here, in the
benchmark's room: rule fine_table, rule ablations_table and ``flatlandia score`` (an outside method's
rows beside the built-in ones) build them alike.
"""

from __future__ import annotations

import pandas as pd

from flatlandia import paper, vocabulary
from flatlandia.benchmark import metrics
from flatlandia.report import tables

#: method slugs (rule wildcards) and their display names (vocabulary.METHOD_LABELS); an external
#: method (config ``external``, ``flatlandia score``) is shown by its summary's ``method``, its name
METHOD_LABELS = vocabulary.METHOD_LABELS


def paper_row(label: str, map_type: str, strategy: str):
    """(name, values) of the paper's row of the same method, map type and proposal: Table 4 by model
    on GT-BB, Table 5 (its MLP on Sim+Trip 2N_LM) on those proposals; ("", NaN...) where the paper has
    no such row (the solver, the whole map, the solver's boxes, another coarse proposal, an external
    method). values = (4 threshold %, median "m", median deg, query ms)."""
    nan = float("nan")
    none = ("", (nan,) * 7)
    if strategy == "GT-BB":
        p = paper.TABLE4.get((label, map_type))
        if p is None:
            return none
        qt = 1000 * paper.MLP_QUERY_S if label == "MLP" else nan
        return f"Table 4 {label}", (*p, qt)
    if label == "MLP" and strategy == "Sim+Trip 2N_LM":
        p5 = paper.TABLE5.get(("MLP", "Sim+Trip", map_type))
        if p5 is not None:
            return "Table 5 MLP Sim+Trip 2N_LM", (nan, nan, nan, nan, p5[0], p5[1], 1000 * paper.MLP_QUERY_S)
    return none


def table_rows(summaries: list[dict]) -> pd.DataFrame:
    """The ``fine_localization`` table (schema in tables.SCHEMAS): one row per run summary, the
    paper's row beside it."""
    nan = float("nan")
    rows = []
    for s in summaries:
        run = s.get("run", "")
        method = s.get("method_slug") or (run.rsplit("_", 2)[0] if run else "")
        label = METHOD_LABELS.get(method, s.get("method", method))
        strategy = s.get("strategy", "")
        name, p = paper_row(label, s.get("map_type", ""), strategy)

        def f(k, scale=1.0, s=s):
            v = s.get(k)
            return nan if v is None else float(v) * scale

        row = {
            "run": run,
            "method": method,
            "method_label": label,
            "map_type": s.get("map_type", ""),
            "proposal": s.get("proposal", run.rsplit("_", 1)[-1] if run else ""),
            "strategy": strategy,
            "queries": int(s.get("queries", 0)),
            "median_m": f("median_m"),
            "median_deg": f("median_deg"),
        }
        row.update({c: f(c) for c in metrics.THRESHOLD_COLUMNS})
        row.update({c: f(c) for c in metrics.RECALL_COLUMNS})
        row[metrics.WITHIN_COLUMN] = f(metrics.WITHIN_COLUMN)
        row.update(
            failure_pct=f("failure_pct"),
            no_pose_pct=f("no_pose_pct"),
            gross_pct=f("gross_pct"),
            median_query_ms=f("median_query_s", 1000),
            mean_query_ms=f("mean_query_s", 1000),
            median_query_cpu_ms=f("median_query_cpu_s", 1000),
            train_s=f("train_s") if s.get("train_s") is not None else 0.0,
            epochs=int(s.get("epochs") or 0),
            n_parameters=int(s.get("n_parameters") or 0),
            model_mb=float(s.get("model_mb") or 0.0),
            ref_map_kb=f("ref_map_kb"),
            median_pu=f("median_pu"),
            # a summary without the key is a learned model's of an older run (GT-BB); the solver's and an
            # external method's are '' (not trained here)
            trained_on=str(
                s.get("trained_on") or (vocabulary.ORACLE_STRATEGY if method in vocabulary.LEARNED_METHODS else "")
            ),
        )
        row.update({c: f(c) for c in metrics.PAPER_UNIT_THRESHOLD_COLUMNS})
        row["paper_row"] = name
        row.update({f"paper_{c}": float(v) for c, v in zip(metrics.THRESHOLD_COLUMNS, p[:4])})
        row.update(paper_median_pu=float(p[4]), paper_median_deg=float(p[5]), paper_query_ms=float(p[6]))
        row.update({c: f(c) for c in metrics.ANSWER_COLUMNS})
        rows.append(row)
    cols = [c.name for c in tables.SCHEMAS["fine_localization"]]
    return pd.DataFrame(rows, columns=cols)
