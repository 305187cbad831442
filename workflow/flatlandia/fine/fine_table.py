"""Fine 3DoF localization, rule fine_table: every run's summary as one row of the
``fine_localization`` table, the paper's row beside it, and Tables 4 and 5 laid out like the
paper's in markdown, then every run's recall at the field's thresholds.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import paper, vocabulary
from flatlandia.benchmark import metrics
from flatlandia.plumbing import escape
from flatlandia.report import tables

#: Tables 4-5: one number per cell, ours then the paper's row of the same method (its metres are
#: local-map units x 215: compare them with our `pu` column)
ACCURACY_COLUMNS = [
    ("median m", "median_m", ".2f"),
    ("median pu", "median_pu", ".2f"),
    ("median °", "median_deg", ".1f"),
    *[(f"% ({m:g} m, {d:g}°)", c, ".1f") for (m, d), c in zip(paper.THRESHOLDS, metrics.THRESHOLD_COLUMNS)],
    ("% (5 m, 5°)", metrics.WITHIN_COLUMN, ".1f"),
    ('paper median "m"', "paper_median_pu", "g"),
    ("paper median °", "paper_median_deg", "g"),
    *[
        (f"paper % ({m:g} m, {d:g}°)", f"paper_{c}", "g")
        for (m, d), c in zip(paper.THRESHOLDS, metrics.THRESHOLD_COLUMNS)
    ],
]
COST_COLUMNS = [
    ("query ms", "median_query_ms", ".1f"),
    ("query CPU ms", "median_query_cpu_ms", ".1f"),
    ("F %", "failure_pct", ".1f"),
    ("no pose %", "no_pose_pct", ".1f"),
    ("gross %", "gross_pct", ".1f"),
    ("train min", "train_min", ".1f"),
    ("epochs", "epochs", "d"),
    ("params", "n_parameters", ","),
    ("model MB", "model_mb", ".2f"),
    ("map kB", "ref_map_kb", ".2f"),
]


def _fmt(v, spec: str) -> str:
    if isinstance(v, str):
        return escape.markdown(v)
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return format(int(v) if spec in ("d", ",") else v, spec)


def _table(rows: pd.DataFrame, columns: list[tuple[str, str, str]], lead: list[tuple[str, str]]) -> list[str]:
    """A markdown table: one row per run, one number per cell."""
    heads = [h for h, _ in lead] + [h for h, _, _ in columns]
    out = ["| " + " | ".join(escape.markdown(h) for h in heads) + " |", "|" + "---|" * len(heads)]
    for r in rows.to_dict("records"):
        cells = [escape.markdown(r[k]) for _, k in lead] + [_fmt(r[k], spec) for _, k, spec in columns]
        out.append("| " + " | ".join(cells) + " |")
    return out


def _ordered(df: pd.DataFrame) -> pd.DataFrame:
    """Runs by table (GT-BB first), then as the config lists them, GT maps before depth maps."""
    return df.assign(_t5=df["strategy"] != "GT-BB", _depth=df["map_type"] == "depth").sort_values(
        ["_t5", "_depth"], kind="stable"
    )


def render_markdown(df: pd.DataFrame, note: str = "") -> str:
    """Tables 4 (GT-BB) and 5 (coarse proposals, whole map) with one number per cell: ours, then the
    paper's row of the same method beside it (empty where the paper has none); every run's recall
    at the field's thresholds (:func:`recall_markdown`); then cost and failures. Values from the runs
    are escaped (:func:`flatlandia.plumbing.escape.markdown`); ``note`` is the caller's Markdown."""
    df = _ordered(df).assign(train_min=df["train_s"] / 60)
    lead = [("method", "method_label"), ("proposal", "strategy"), ("map", "map_type")]
    out = [
        "# Fine 3DoF localization (test split)",
        "",
        "Errors in true metres; `pu`: the paper's convention (local-map units x 215), the unit of the paper's "
        '"m" columns; % of queries under each (metres, degrees) threshold at once, (5 m, 5°) the share a user '
        "would call localized. The paper's columns hold its row of the same method, map type and proposal, "
        "empty where it has none (the solver, the whole map, the solver's boxes). GT local maps are exact rigid "
        "copies of the reference map: on them the task is pure registration.",
        "",
    ]
    if note:
        out += [note, ""]
    for title, mask in (
        ("Table 4 (GT-BB proposals)", df["strategy"] == "GT-BB"),
        ("Table 5 (coarse proposals and whole map)", df["strategy"] != "GT-BB"),
    ):
        part = df[mask]
        if not part.empty:
            out += [f"## {title}", ""] + _table(part, ACCURACY_COLUMNS, lead) + [""]
    out += recall_markdown(df)
    out += answers_markdown(df)
    out += [
        "## Cost and failures",
        "",
        "Median time per query (one CPU thread; wall and CPU), F % (the proposal holds fewer than 3 objects of "
        "the query's classes), queries without a pose, gross errors (> 30 m), training (one CPU thread) and "
        "model size for the learned models, the reference map's size as the methods read it.",
        "",
        *_table(df, COST_COLUMNS, lead + [("trained on", "trained_on")]),
        "",
    ]
    return "\n".join(out) + "\n"


def recall_markdown(df: pd.DataFrame) -> list[str]:
    """Every run's recall at the field's thresholds, OrienterNet's published MGL row under them: a
    table of its own, so that Tables 4-5 keep the paper's layout. Lines of markdown."""
    heads = [f"{m:g} m" for m in metrics.RECALL_M] + [f"{d:g}°" for d in metrics.RECALL_DEG]
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
        "| method | proposal | map type | " + " | ".join(heads) + " | (5 m, 5°) |",
        "|---|---|---|" + "---|" * (len(heads) + 1),
    ]
    for r in _ordered(df).to_dict("records"):
        cols = [*metrics.RECALL_COLUMNS, metrics.WITHIN_COLUMN]
        cells = ["–" if not np.isfinite(r.get(c, float("nan"))) else f"{r[c]:.1f}" for c in cols]
        labels = [escape.markdown(r[c]) for c in ("method_label", "strategy", "map_type")]
        out.append("| " + " | ".join(labels + cells) + " |")
    theirs = [paper.ORIENTERNET_MGL_RECALL_M[m] for m in metrics.RECALL_M] + [
        paper.ORIENTERNET_MGL_RECALL_DEG[d] for d in metrics.RECALL_DEG
    ]
    out.append(
        "| OrienterNet, MGL (another task) | OSM raster, 100-200 m prior | image | "
        + " | ".join(f"{v:.1f}" for v in theirs)
        + " | – |"
    )
    return out + [""]


#: the answers' columns of the markdown: the solver's probability and what answering at its threshold gives
ANSWER_MARKDOWN = [
    ("% answered", "answered_pct", ".1f"),
    ("% within (5 m, 5°) of the answered", "within_answered_pct", ".1f"),
    ("% within (5 m, 5°) of all", metrics.WITHIN_COLUMN, ".1f"),
    ("answerable at ≥ 95 % within, %", "answerable_95_pct", ".1f"),
    ("calibration error, points", "ece_points", ".1f"),
]


def answers_markdown(df: pd.DataFrame) -> list[str]:
    """The runs that give a probability (the solver's): % answered at ``solver.answer_probability``,
    the answered within (5 m, 5°), and the largest share answerable at ≥ 95 % within. Lines."""
    rows = df[np.isfinite(df["answerable_95_pct"].to_numpy(float))] if "answerable_95_pct" in df else df.iloc[:0]
    if rows.empty:
        return []
    lead = [("method", "method_label"), ("proposal", "strategy"), ("map", "map_type")]
    return [
        "## Knowing when it is right",
        "",
        "The solver's answers carry the calibrated probability of being within (5 m, 5°) (docs/results.md, "
        '"Knowing when it is right"): answered are those at or above `solver.answer_probability` (status ok), the '
        "rest are `ambiguous`; answerable at ≥ 95 %: the largest share of the queries that can be answered, surest "
        "first, with at least 95 % of them within (5 m, 5°); calibration error: expected calibration error of "
        "the probability (10 bins).",
        "",
        *_table(_ordered(rows), ANSWER_MARKDOWN, lead),
        "",
    ]


# ----------------------------------------------------------------------------- per scene


def per_scene_runs(df: pd.DataFrame) -> list[str]:
    """The runs of the per-scene table: per map type the solver on GT-BB and on the whole map, and the
    learned run on GT-BB with the lowest median position error over every scene."""
    runs = []
    for mt in vocabulary.MAP_TYPES:
        mine = df[df["map_type"] == mt]
        solver_runs = (vocabulary.run_name("solver", mt, p) for p in (vocabulary.GTBB, vocabulary.WHOLE))
        runs += [r for r in solver_runs if r in set(mine["run"])]
        learned = mine[(mine["proposal"] == vocabulary.GTBB) & mine["method"].isin(set(vocabulary.LEARNED_METHODS))]
        if len(learned):
            runs.append(str(learned.sort_values("median_m", kind="stable")["run"].iloc[0]))
    return runs


def per_scene_rows(df: pd.DataFrame, errors: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """The ``fine_per_scene`` table: each scene's test queries under the runs of :func:`per_scene_runs`
    (``errors``: run -> its errors.parquet), one row per scene and run."""
    rows = []
    for run in per_scene_runs(df):
        meta = df.set_index("run").loc[run]
        for scene, e in errors[run].groupby(errors[run]["scene"].astype(str), sort=False):
            s = metrics.summarise(e)
            rows.append(
                {
                    "scene": scene,
                    "map_type": meta["map_type"],
                    "run": run,
                    "method_label": meta["method_label"],
                    "strategy": meta["strategy"],
                    "queries": int(s["queries"]),
                    "median_m": s["median_m"],
                    "median_deg": s["median_deg"],
                    "within_5m_5deg": s[metrics.WITHIN_COLUMN],
                }
            )
    cols = [c.name for c in tables.SCHEMAS["fine_per_scene"]]
    out = pd.DataFrame(rows, columns=cols)
    return out.sort_values(["map_type", "scene"], key=_scene_key, kind="stable", ignore_index=True)


def _scene_key(col: pd.Series) -> pd.Series:
    if col.name == "scene":  # numeric ids in numeric order, then the others
        return col.map(lambda s: (0, int(s), "") if str(s).isdigit() else (1, 0, str(s)))
    return col.map(lambda m: {"gt": 0, "depth": 1}.get(m, 2))


def per_scene_markdown(rows: pd.DataFrame) -> str:
    """Per map type, one row per scene and, per run, its median position error and % within (5 m, 5°):
    one number per cell."""
    out = [
        "# Fine localization per scene (test split)",
        "",
        "Per scene: the geometric solver on GT-BB and on the whole map, and the learned model that is best on "
        "GT-BB over all scenes; median position error in true metres and % of the scene's test queries within "
        "5 m and 5° at once. Few test queries per scene (10 % of its queries): read the figures with their count.",
        "",
    ]
    for mt, part in rows.groupby("map_type", sort=False):
        runs = list(dict.fromkeys(part["run"]))
        label = {
            r: f"{part.loc[part['run'] == r, 'method_label'].iloc[0]}, {part.loc[part['run'] == r, 'strategy'].iloc[0]}"
            for r in runs
        }
        heads = ["scene", "queries"] + [h for r in runs for h in (f"{label[r]}: median m", f"{label[r]}: % (5 m, 5°)")]
        out += [f"## {'GT' if mt == 'gt' else 'depth'} local maps", ""]
        out += ["| " + " | ".join(escape.markdown(h) for h in heads) + " |", "|" + "---|" * len(heads)]
        for scene, g in part.groupby("scene", sort=False):
            by = g.set_index("run")
            cells = [escape.markdown(scene), str(int(g["queries"].iloc[0]))]
            for r in runs:
                cells += (
                    [_fmt(by.loc[r, "median_m"], ".2f"), _fmt(by.loc[r, "within_5m_5deg"], ".1f")]
                    if r in by.index
                    else ["–", "–"]
                )
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)
