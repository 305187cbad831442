"""The tiny scene (tests/data/tiny) for the tests, through the package's one recipe
(:func:`flatlandia.data.scene_inputs.published_scene`: rules reference_map -> recover -> queries in
process, no Snakemake): :func:`tiny_scene` (its tables, once a session) and :func:`build` (a results
folder as the workflow lays it out: reference map with its frame in the Parquet metadata, queries,
the benchmark record, and the solver's depth runs (train split: 10 queries; the test split holds
one) with their fine table; used by the scoring tests and the installed wheel's test)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pandas as pd
from conftest import TINY_ROOT, TINY_SCENE

from flatlandia import config, score
from flatlandia.benchmark import fine_rows, metrics, solver_runs
from flatlandia.data import scene_inputs
from flatlandia.plumbing import files


@functools.cache
def _tiny_scene() -> scene_inputs.SceneInputs:
    return scene_inputs.published_scene(TINY_ROOT, TINY_SCENE)


def tiny_scene() -> scene_inputs.SceneInputs:
    """The tiny scene's inputs as the rules make them (built once a session; each caller gets its
    own copy of the tables, so a test may change them)."""
    s = _tiny_scene()
    return scene_inputs.SceneInputs(
        s.scene,
        s.lonlat.copy(),
        s.classes.copy(),
        {t: {k: v.copy() for k, v in m.items()} for t, m in s.local_maps.items()},
        s.ref.copy(),
        json.loads(json.dumps(s.meta)),
        s.recovered.copy(),
        s.queries.copy(),
        json.loads(json.dumps(s.queries_meta)),
    )


def builtin_summary(errors: pd.DataFrame, method: str, map_type: str, proposal: str, label: str, ref) -> dict:
    """A built-in run's summary as rule fine_eval writes it (the solver's)."""
    s = metrics.summarise(errors)
    s.update(
        method=str(errors["method"].iloc[0]),
        method_slug=method,
        map_type=map_type,
        proposal=proposal,
        strategy=label,
        run=f"{method}_{map_type}_{proposal}",
        ref_map_kb=metrics.ref_map_kb(ref),
        train_s=0.0,
        epochs=0,
        trained_on="",
    )
    return s


def build(root: Path) -> Path:
    """Write the tiny scene's results folder at ``root`` (…/results) and return it."""
    tiny = tiny_scene()
    ref, q = tiny.ref, tiny.queries
    tiny.write(root)
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE]}), root / score.BENCHMARK_RECORD)
    summaries = []
    for proposal, label in (("whole", "whole map"), ("gtbb", "GT-BB")):
        e = solver_runs.solver_errors([(ref, q)], "depth", proposal, config.section_defaults("solver"), split="train")
        e["strategy"] = label
        folder = root / "fine" / f"solver_depth_{proposal}"
        files.write_parquet(e, folder / "errors.parquet")
        summaries.append(builtin_summary(e, "solver", "depth", proposal, label, ref))
        files.write_json(files.json_safe(summaries[-1]), folder / "summary.json")
    files.write_parquet(fine_rows.table_rows(summaries), root / "tables" / "fine_localization.parquet")
    return root
