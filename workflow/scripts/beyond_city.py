"""Rule beyond_city: every test anchor's sequences and GPS fixes searched in a city, `city-N` (the
tiled city of N scenes, rule city_maps and city_index) or `simulated-N` (each scene among
synthetic tiles, the cities of rule city_simulate) (flatlandia.sequences.evaluation); per-anchor errors
and the summary rows of the table beyond_one_frame."""

from pathlib import Path

import pandas as pd

from flatlandia import solver
from flatlandia.city.index import ViewIndex
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.files import json_safe
from flatlandia.sequences import evaluation
from flatlandia.solver.learned_priors import read_map_size


def main(smk, log):
    beyond = dict(smk.params["beyond"])
    kind, n = smk.wildcards.map.split("-")
    settings = evaluation.settings_grid(beyond, True)
    learned = solver.LearnedPriors.read(smk.input.priors).with_map_size(read_map_size(smk.input.calibration))
    common = dict(
        settings=settings,
        solver_settings=dict(smk.params["solver"]),
        search_settings=dict(smk.params["city.search"]),
        beyond=beyond,
        learned=learned,
        seed=int(smk.params["seed"]),
        split=beyond["split"],
        log=log,
    )
    if kind == "city":
        maps = pd.read_parquet(smk.input.map)
        index_dir = Path(smk.input.index)

        def index_of(city: str) -> ViewIndex:
            return ViewIndex.load(index_dir / f"{city}.npz")

        errors = evaluation.tiled_city_errors(
            maps, pd.read_parquet(smk.input.queries), index_of, map_name=smk.wildcards.map, **common
        )
        objects = int(round(maps.groupby("city").size().mean()))
    else:
        scenes = list(smk.params.scene_ids)
        errors = evaluation.simulated_city_errors(
            scenes,
            {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.reference_maps)},
            {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.queries)},
            int(n),
            dict(smk.params["city.simulate"]),
            float(smk.params["city.spacing_m"]),
            **common,
        )
        objects = int(errors.attrs.get("objects", n))
    rows = evaluation.summaries(errors, {smk.wildcards.map: objects})
    files.write_parquet(
        errors, smk.output.errors, {"split": beyond["split"], "beyond": beyond, "map": smk.wildcards.map}
    )
    files.write_json([json_safe(r) for r in rows], smk.output.summary)
    for r in rows:
        log.info("%s", r)


rule_log.run(main, snakemake)  # noqa: F821
