"""Rule city_simulate: the city search in synthetic cities of {objects} objects
(flatlandia.city.evaluation.simulated_errors).

Each benchmark scene's queries are localized in a city of that scene and synthetic tiles drawn
from the other scenes (flatlandia.city.simulate), indexed as rule city_index does; the index is
built here because these maps exist only for the measurement. Today's solver is not run: its
whole-map search needs a (views x objects) co-visibility matrix, 7 GB at 100,000 objects.
"""

import pandas as pd

from flatlandia import solver
from flatlandia.city import evaluation, search
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.files import json_safe
from flatlandia.solver.learned_priors import read_map_size


def main(smk, log):
    scenes = list(smk.params.scene_ids)
    n_objects, split, sim = int(smk.wildcards.objects), smk.params["city.split"], smk.params["city.simulate"]
    errors, out = evaluation.simulated_errors(
        scenes,
        {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.reference_maps)},
        {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.queries)},
        n_objects,
        float(smk.params["city.spacing_m"]),
        sim,
        int(smk.params["seed"]),
        split,
        search.SearchConfig.from_dict(smk.params["city.search"]),
        dict(smk.params["solver"]),
        solver.LearnedPriors.read(smk.input.priors).with_map_size(read_map_size(smk.input.calibration)),
        log=log,
    )
    files.write_parquet(errors, smk.output.errors, {"objects": n_objects, "split": split, "simulate": dict(sim)})
    files.write_json(json_safe(out), smk.output.summary)
    log.info("summary: %s", out)


rule_log.run(main, snakemake)  # noqa: F821
