"""Rule city_eval: one method on every city of {n} scenes; per-query errors and the summary row.

``solver``: today's solver on each whole city map; ``index``: the city search with each city's
saved index (flatlandia.city.evaluation.tiled_errors).
"""

import json
from pathlib import Path

import pandas as pd

from flatlandia import solver
from flatlandia.city import evaluation, search
from flatlandia.city.index import ViewIndex
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.files import json_safe
from flatlandia.solver.learned_priors import read_map_size


def main(smk, log):
    method, cfg = smk.wildcards.method, search.SearchConfig.from_dict(smk.params["city.search"])
    index_dir = Path(smk.input.index) if method == "index" else None
    learned = solver.LearnedPriors.read(smk.input.priors)
    if method == "index":  # the index ranks the whole city: the map-size correction (rule city_calibration)
        learned = learned.with_map_size(read_map_size(smk.input.calibration))

    def index_of(city: str) -> ViewIndex:
        return ViewIndex.load(index_dir / f"{city}.npz")

    errors, out = evaluation.tiled_errors(
        pd.read_parquet(smk.input.map),
        pd.read_parquet(smk.input.queries),
        int(smk.wildcards.n),
        method,
        smk.params["city.split"],
        cfg,
        dict(smk.params["solver"]),
        learned,
        index_of=index_of,
        built=json.loads((index_dir / "build.json").read_text()) if index_dir else None,
        log=log,
    )
    meta = {"method": method, "split": smk.params["city.split"], "search": cfg.to_dict()}
    files.write_parquet(errors, smk.output.errors, meta)
    files.write_json(json_safe(out), smk.output.summary)
    log.info("summary: %s", out)


rule_log.run(main, snakemake)  # noqa: F821
