"""``flatlandia score``'s report: scores.md, the method's rows beside the built-in rows of the same
setting (:func:`scores_markdown`), and every run's files (:func:`write_scores`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import paper, vocabulary
from flatlandia.benchmark import fine_rows, metrics
from flatlandia.plumbing import escape, files
from flatlandia.score.external_runs import Scores

#: the columns of scores.md: what the run is, then every threshold and recall, failures
#: (the README's headline, % within (5 m, 5°), among the paper's thresholds in their order)
SCORE_COLUMNS = (
    ["queries", "median_m", "median_deg"]
    + metrics.THRESHOLD_COLUMNS[:2]
    + [metrics.WITHIN_COLUMN]
    + metrics.THRESHOLD_COLUMNS[2:]
    + metrics.RECALL_COLUMNS
    + ["no_pose_pct", "failure_pct", "gross_pct"]
)
#: the columns scores.md adds for a poses file with answers (a status column): the fine table's
#: % answered and % within (5 m, 5°) of the answered
ANSWER_SCORE_COLUMNS = ["answered_pct", "within_answered_pct"]


def scores_markdown(scores: Scores, name: str, poses_path: str) -> str:
    """scores.md: per setting, the method's row beside the built-in rows of the same map type
    and proposal (every threshold and recall column; for a file with answers, the answered share
    and the within (5 m, 5°) of the answered)."""

    thresholds = [f"{m:g} m & {d:g}°" for m, d in paper.THRESHOLDS]
    heads = (
        ["queries", "median m", "median °"]
        + thresholds[:2]
        + ["{:g} m & {:g}°".format(*metrics.WITHIN)]
        + thresholds[2:]
        + [f"recall {m:g} m" for m in metrics.RECALL_M]
        + [f"recall {d:g}°" for d in metrics.RECALL_DEG]
        + ["no pose %", "F %", "gross %"]
    )
    out = [
        f"# Scores of {escape.markdown(name)}",
        "",
        f"Poses: `{escape.markdown(poses_path)}`, scored on the {escape.markdown(scores.runs[0].summary['split'])} split "
        "with the built-in methods' functions (true metres; queries without a pose are failures: infinite error, "
        "180°). Threshold columns: % of queries under both the position and the heading threshold; recalls: "
        "position and heading apart.",
        "",
    ]
    for note in scores.notes:
        out += [f"Note: {escape.markdown(note)}", ""]
    for w in scores.warnings:
        out += [f"**Warning**: {escape.markdown(w)}", ""]
    for run in scores.runs:
        s = run.summary
        columns, run_heads = SCORE_COLUMNS, heads
        if s.get("has_status"):
            columns = SCORE_COLUMNS + ANSWER_SCORE_COLUMNS
            run_heads = heads + ["answered %", "{:g} m & {:g}° of the answered".format(*metrics.WITHIN)]
        mine = fine_rows.table_rows([s])
        rows = [mine]
        if scores.builtin is not None:
            same = scores.builtin[
                (scores.builtin["map_type"] == run.map_type) & (scores.builtin["proposal"] == run.proposal)
            ]
            rows.append(same)
        df = pd.concat(rows, ignore_index=True)
        out += [
            f"## {escape.markdown(run.map_type)} local maps, {escape.markdown(s['strategy'])} proposals",
            "",
            f"{s['queries']} queries, {s['scored']} scored, {s['missing']} missing (failures)."
            + (f" Answered: status {vocabulary.ANSWERED} in the file." if s.get("has_status") else ""),
            "",
            "| method | " + " | ".join(run_heads) + " |",
            "|---|" + "---|" * len(run_heads),
        ]
        for r in df.to_dict("records"):
            cells = []
            for c in columns:
                v = r[c]
                if c == "queries":
                    cells.append(str(int(v)))
                else:
                    cells.append(
                        "–" if v is None or not np.isfinite(v) else f"{v:.2f}" if c.startswith("median") else f"{v:.1f}"
                    )
            method = escape.markdown(r["method_label"]) + (" (yours)" if r["run"] == run.run else "")
            out.append(f"| {method} | " + " | ".join(cells) + " |")
        if len(df) == 1:
            out += ["", "No built-in run of this setting in the results folder."]
        out.append("")
    return "\n".join(out)


def write_scores(scores: Scores, name: str, poses_path: str, out: str | Path, *, reads=(), artifacts=()) -> list[Path]:
    """Write each run's errors.parquet and summary.json (rule fine_eval's shapes) under
    ``out/{name}_{map_type}_{proposal}/`` and ``out/scores.md``, staged together and moved into place
    as one (:func:`flatlandia.plumbing.files.staged`: a failed write leaves the older set whole, never
    new runs beside a stale scores.md); ``reads``/``artifacts``: what the write door refuses to replace.
    The paths written."""
    out = Path(out)
    names = [f"{run.run}/{part}" for run in scores.runs for part in ("errors.parquet", "summary.json")]
    with files.staged(out, [*names, "scores.md"], reads=reads, artifacts=artifacts) as tmp:
        for run in scores.runs:
            run.write(tmp[f"{run.run}/errors.parquet"], tmp[f"{run.run}/summary.json"])
        files.write_text(scores_markdown(scores, name, poses_path), tmp["scores.md"])
    return [out / n for n in [*names, "scores.md"]]
