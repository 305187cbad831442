"""An images scene evaluated with the benchmark's methods (rule scene_localization).

Why: a user's own photos become a new scene; how well do the models trained on the published
scenes localize its queries? Nothing is retrained and nothing is fitted on the new scene: the
geometric solver runs without priors from it (no camera or scale prior), the learned models
are the benchmark's checkpoints. Every query of the scene is a test query (no model saw it).
Rows of their own, one per method x map type x proposal, with a ``scene`` column.
"""

from __future__ import annotations

from collections.abc import Callable

import pandas as pd

from flatlandia import proposals, vocabulary
from flatlandia.benchmark import metrics, solver_runs
from flatlandia.fine import evaluation
from flatlandia.plumbing import escape

#: proposals a new scene is evaluated on: the oracle box and the whole map (coarse proposals
#: need the coarse model's retrieval over the scene, which the benchmark tables cover)
SCENE_PROPOSALS = {p: vocabulary.strategy_label(p) for p in vocabulary.MAP_PROPOSALS}

ROW_COLUMNS = ["scene", "method", "method_slug", "map_type", "proposal", "strategy"]


def scene_rows(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    models: dict[tuple[str, str], tuple],
    map_types: list[str],
    solver_config: dict,
    progress: Callable | None = None,
) -> pd.DataFrame:
    """Summary rows of the solver (``solver``) and of each model ``models[(slug, map_type)] =
    (model, FineTrainConfig)`` on every query of one scene; an empty table for a scene without queries."""
    scene = str(ref["scene"].iloc[0]) if len(ref) else ""
    rows = []
    if len(queries) == 0:
        return pd.DataFrame(columns=ROW_COLUMNS + ["queries", "median_m", "median_deg"])
    no_prior = {**solver_config, "camera_prior": False, "scale_prior": False}
    for proposal, label in SCENE_PROPOSALS.items():
        make = proposals.gtbb_proposals if proposal == vocabulary.GTBB else proposals.whole_map_proposals
        props = make(ref, queries)
        for map_type in map_types:
            errors = solver_runs.evaluate_solver(
                ref, queries, props, map_type, no_prior, method="geometric solver", progress=progress
            )
            rows.append(_row(scene, "geometric solver", "solver", map_type, proposal, label, errors))
            for (slug, mt), (model, cfg) in sorted(models.items()):
                if mt == map_type:
                    errors = evaluation.evaluate_model(model, cfg, ref, queries, props)
                    rows.append(_row(scene, cfg.model, slug, map_type, proposal, label, errors))
    return pd.DataFrame(rows)


def _row(scene, method, slug, map_type, proposal, label, errors: pd.DataFrame) -> dict:
    return {
        "scene": scene,
        "method": method,
        "method_slug": slug,
        "map_type": map_type,
        "proposal": proposal,
        "strategy": label,
        **metrics.summarise(errors),
    }


def render_markdown(rows: pd.DataFrame, scene: str) -> str:
    """The scene's rows as a Markdown table (true metres; % under the paper's thresholds, then the
    field's recalls: position and heading apart); the scene id and the cells escaped
    (:func:`flatlandia.plumbing.escape.markdown`)."""
    head = f"# Scene {escape.markdown(scene)}: localization with the benchmark's methods (no retraining)\n\n"
    if rows.empty:
        return head + "No rows: the scene has no query (see results/summary.md for why).\n"
    cols = ["method", "map_type", "strategy", "queries", "median_m", "median_deg"]
    cols += metrics.THRESHOLD_COLUMNS + metrics.RECALL_COLUMNS
    lines = ["| " + " | ".join(escape.markdown(c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows[cols].to_dict("records"):
        cells = [f"{r[c]:.2f}" if isinstance(r[c], float) else escape.markdown(r[c]) for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"
