"""A results folder of the tiny scene (tests/data/tiny) as the workflow lays it out, built in-process
from the package's functions (no Snakemake): its reference map (frame in the Parquet metadata),
queries, the benchmark record, and the solver's depth runs (train split: 10 queries; the test split
holds one) with their fine table. Used by the scoring tests and the installed wheel's test."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from conftest import TINY_ROOT, TINY_SCENE

from flatlandia import config, geo, io, score
from flatlandia.classes import CLASSES
from flatlandia.data import queries, recover, reference_map
from flatlandia.fine import evaluation
from flatlandia.fine import table as fine_table


def builtin_summary(errors: pd.DataFrame, method: str, map_type: str, proposal: str, label: str, ref) -> dict:
    """A built-in run's summary as rule fine_eval writes it (the solver's)."""
    s = evaluation.summarise(errors)
    s.update(
        method=str(errors["method"].iloc[0]),
        method_slug=method,
        map_type=map_type,
        proposal=proposal,
        strategy=label,
        run=f"{method}_{map_type}_{proposal}",
        ref_map_kb=evaluation.ref_map_kb(ref),
        train_s=0.0,
        epochs=0,
        trained_on="",
    )
    return s


def build(root: Path) -> Path:
    """Write the tiny scene's results folder at ``root`` (…/results) and return it."""
    lonlat, classes = io.read_reference_map(
        TINY_ROOT / f"individual_reference_maps/map_{TINY_SCENE}.json", len(CLASSES)
    )
    frame = geo.frame_for(lonlat)
    ref = reference_map.reference_table(TINY_SCENE, lonlat, classes, CLASSES, frame)
    local = io.read_local_maps(TINY_ROOT / "local_maps.json", TINY_SCENE)
    rec = recover.recover_scene(TINY_SCENE, lonlat, classes, local)
    split = queries.split_queries(list(rec["token"]), 0, salt=TINY_SCENE)
    q = queries.build_queries(TINY_SCENE, rec, ref, local, frame, split)
    reference_map.write_geoparquet(
        ref,
        reference_map.frame_metadata(TINY_SCENE, frame),
        root / TINY_SCENE / "maps" / "reference_map.parquet",
    )
    io.write_parquet(q, root / TINY_SCENE / "queries" / "queries.parquet")
    io.write_parquet(pd.DataFrame({"scene": [TINY_SCENE]}), root / score.BENCHMARK_RECORD)
    summaries = []
    for proposal, label in (("whole", "whole map"), ("gtbb", "GT-BB")):
        e = evaluation.solver_errors([(ref, q)], "depth", proposal, config.section_defaults("solver"), split="train")
        e["strategy"] = label
        folder = root / "fine" / f"solver_depth_{proposal}"
        io.write_parquet(e, folder / "errors.parquet")
        summaries.append(builtin_summary(e, "solver", "depth", proposal, label, ref))
        io.write_json(evaluation.json_safe(summaries[-1]), folder / "summary.json")
    io.write_parquet(fine_table.table_rows(summaries), root / "tables" / "fine_localization.parquet")
    return root
