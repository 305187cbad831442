"""Fine 3DoF localization, rule fine_table: every run's summary as one row of the
``fine_localization`` table, the paper's row beside it, and Tables 4 and 5 laid out like the
paper's in markdown, then every run's recall at the field's thresholds.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import escape, paper, tables
from flatlandia.fine import evaluation

#: method slugs (rule wildcards) and their display names; an external method (config ``external``,
#: ``flatlandia score``) is shown by its summary's ``method``, its name
METHOD_LABELS = {"solver": "geometric solver", "mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}


def paper_row(label: str, map_type: str, strategy: str):
    """(name, values) of the paper's row beside ours: Table 4 by model (its best, MLP, for the
    solver) for GT-BB; Table 5's best (MLP, Sim+Trip 2N_LM) for coarse proposals and the whole map.
    values = (4 threshold %, median "m", median deg, query ms); NaN where the paper gives none."""
    nan = float("nan")
    if strategy == "GT-BB":
        p = paper.TABLE4.get((label, map_type))
        name = label
        if p is None:
            p, name = paper.TABLE4[("MLP", map_type)], "MLP (best)"
        qt = 1000 * paper.MLP_QUERY_S if name.startswith("MLP") and not name.startswith("MLP+") else nan
        return f"Table 4 {name}", (*p, qt)
    p5 = paper.TABLE5.get(("MLP", "Sim+Trip", map_type))
    if p5 is None:
        return "", (nan,) * 7
    return "Table 5 MLP Sim+Trip 2N_LM (best)", (nan, nan, nan, nan, p5[0], p5[1], 1000 * paper.MLP_QUERY_S)


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
        row.update({c: f(c) for c in evaluation.THRESHOLD_COLUMNS})
        row.update({c: f(c) for c in evaluation.RECALL_COLUMNS})
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
            trained_on=str(s.get("trained_on") or ("GT-BB" if method in METHOD_LABELS and method != "solver" else "")),
        )
        row.update({c: f(c) for c in evaluation.PAPER_UNIT_THRESHOLD_COLUMNS})
        row["paper_row"] = name
        row.update({f"paper_{c}": float(v) for c, v in zip(evaluation.THRESHOLD_COLUMNS, p[:4])})
        row.update(paper_median_pu=float(p[4]), paper_median_deg=float(p[5]), paper_query_ms=float(p[6]))
        rows.append(row)
    cols = [c.name for c in tables.SCHEMAS["fine_localization"]]
    return pd.DataFrame(rows, columns=cols)


def render_markdown(df: pd.DataFrame, note: str = "") -> str:
    """Tables 4 (GT-BB) and 5 (coarse proposals, whole map) laid out like the paper, its values beside
    ours; then every run's recall at the field's thresholds (:func:`recall_markdown`). Values from the
    runs are escaped (:func:`flatlandia.escape.markdown`); ``note`` is the caller's Markdown."""

    def fmt(v, spec):
        return "–" if v is None or not np.isfinite(v) else format(v, spec)

    def cell(r):
        pct = " / ".join(fmt(r[c], ".1f") for c in evaluation.THRESHOLD_COLUMNS)
        out = (
            f"{pct}; {fmt(r['median_m'], '.2f')} m ({fmt(r['median_pu'], '.2f')} pu); {fmt(r['median_deg'], '.1f')}°; "
            f"QT {fmt(r['median_query_ms'], '.1f')} ms (CPU {fmt(r['median_query_cpu_ms'], '.1f')} ms); F {fmt(r['failure_pct'], '.1f')}%; "
            f"gross {fmt(r['gross_pct'], '.1f')}%"
        )
        if r["epochs"]:
            trained_on = escape.markdown(r["trained_on"] or "GT-BB")
            out += f"; train {fmt(r['train_s'] / 60, '.1f')} min ({r['epochs']} ep, {trained_on})"
        return out

    def paper_cell(r):
        if not r["paper_row"]:
            return "—"
        pre = (
            ""
            if r["paper_row"].endswith(r["method_label"])
            else escape.markdown(r["paper_row"].split(" ", 2)[-1]) + ": "
        )
        pct = (
            " / ".join(fmt(r[f"paper_{c}"], "g") for c in evaluation.THRESHOLD_COLUMNS) + "; "
            if np.isfinite(r[f"paper_{evaluation.THRESHOLD_COLUMNS[0]}"])
            else ""
        )
        qt = f"; {fmt(r['paper_query_ms'], 'g')} ms" if np.isfinite(r["paper_query_ms"]) else ""
        return f'{pre}{pct}{fmt(r["paper_median_pu"], "g")} "m"; {fmt(r["paper_median_deg"], "g")}°{qt}'

    out = [
        "# Fine 3DoF localization (test split)",
        "",
        "Cells: % within (0.5 m, 2°) / (1 m, 5°) / (5 m, 10°) / (10 m, 20°) in true metres; median error in true "
        "metres (in brackets, `pu`: the paper's convention, local-map units x 215); median degrees; median query "
        "time (one CPU thread); F% (proposal holds fewer than 3 objects of the query's classes); gross errors "
        "(> 30 m); training time (one CPU thread) for learned models.",
        'The paper\'s columns are its own figures, whose metres are units x 215 ("m"). GT local maps are exact '
        "rigid copies of the reference map: on them the task is pure registration.",
        "",
    ]
    if note:
        out += [note, ""]
    for title, mask in (
        ("Table 4 (GT-BB proposals)", df["strategy"] == "GT-BB"),
        ("Table 5 (coarse proposals and whole map)", df["strategy"] != "GT-BB"),
    ):
        part = df[mask]
        if part.empty:
            continue
        out += [
            f"## {title}",
            "",
            "| method | proposal | GT maps (ours) | GT maps (paper) | depth maps (ours) | "
            "depth maps (paper) | params / model / map |",
            "|---|---|---|---|---|---|---|",
        ]
        for (label, strategy), g in part.groupby(["method_label", "strategy"], sort=False):
            cells = []
            for mt in ("gt", "depth"):
                r = g[g["map_type"] == mt]
                cells += [cell(r.iloc[0]), paper_cell(r.iloc[0])] if len(r) else ["—", "—"]
            r0 = g.iloc[0]
            size = (
                f"{r0['n_parameters']:,} / {r0['model_mb']:.2f} MB / {r0['ref_map_kb']:.2f} kB"
                if r0["n_parameters"]
                else f"– / – / {r0['ref_map_kb']:.2f} kB"
            )
            out.append(
                f"| {escape.markdown(label)} | {escape.markdown(strategy)} | " + " | ".join(cells) + f" | {size} |"
            )
        out.append("")
    return "\n".join(out + recall_markdown(df)) + "\n"


def recall_markdown(df: pd.DataFrame) -> list[str]:
    """Every run's recall at the field's thresholds, OrienterNet's published MGL row under them: a
    table of its own, so that Tables 4-5 keep the paper's layout. Lines of markdown."""
    heads = [f"{m:g} m" for m in evaluation.RECALL_M] + [f"{d:g}°" for d in evaluation.RECALL_DEG]
    out = [
        "## Recall at the field's thresholds",
        "",
        "% of test queries under 1 / 3 / 5 m (any heading) and, apart, under 1 / 3 / 5° (any position), true "
        "metres; failed queries are misses. The whole-map rows have no per-query location prior (the geometric "
        "solver keeps its poses near the training split's cameras when `solver.camera_prior` is on); GT-BB is "
        "an oracle box around the query's objects; GT local maps make the task pure registration. OrienterNet's "
        "row is another benchmark (MGL: one image against an OpenStreetMap raster, a 100-200 m location prior, "
        "a GPU), quoted for scale, not as a baseline of this task (an object map registered against an object "
        "map).",
        "",
        "| method | proposal | map type | " + " | ".join(heads) + " |",
        "|---|---|---|" + "---|" * len(heads),
    ]
    order = df.assign(_gtbb=df["strategy"] != "GT-BB").sort_values("_gtbb", kind="stable")
    for r in order.to_dict("records"):
        cells = ["–" if not np.isfinite(r[c]) else f"{r[c]:.1f}" for c in evaluation.RECALL_COLUMNS]
        labels = [escape.markdown(r[c]) for c in ("method_label", "strategy", "map_type")]
        out.append("| " + " | ".join(labels + cells) + " |")
    theirs = [paper.ORIENTERNET_MGL_RECALL_M[m] for m in evaluation.RECALL_M] + [
        paper.ORIENTERNET_MGL_RECALL_DEG[d] for d in evaluation.RECALL_DEG
    ]
    out.append(
        "| OrienterNet, MGL (another task) | OSM raster, 100-200 m prior | image | "
        + " | ".join(f"{v:.1f}" for v in theirs)
        + " |"
    )
    return out + [""]
