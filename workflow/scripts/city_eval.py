"""Rule city_eval: one method on every city of {n} scenes; per-query errors and the summary row.

``solver``: today's solver on each whole city map; ``index``: the city search with each city's
saved index (flatlandia.city.evaluate).
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import io, runlog, solver
from flatlandia.city import evaluate, search
from flatlandia.city.index import ViewIndex
from flatlandia.fine import evaluation


def main(smk, log):
    maps, queries = pd.read_parquet(smk.input.map), pd.read_parquet(smk.input.queries)
    learned = solver.LearnedPriors.read(smk.input.priors)
    settings, split, method = dict(smk.params.solver), smk.params.split, smk.wildcards.method
    cfg = search.SearchConfig.from_dict(smk.params.search)
    parts, built = [], []
    for city, ref in maps.groupby("city", sort=True):
        q = queries[queries["city"] == city]
        if method == "solver":
            parts.append(evaluate.solver_errors(ref, q, split, settings, learned))
        else:
            ix = ViewIndex.load(Path(smk.input.index) / f"{city}.npz")
            parts.append(evaluate.index_errors(ix, q, split, cfg, settings, learned))
        log.info("city %s: %s", city, evaluate.summary(parts[-1]) if len(parts[-1]) else "no queries")
    if method == "index":
        built = json.loads((Path(smk.input.index) / "build.json").read_text())
    errors = pd.concat(parts, ignore_index=True)
    out = evaluate.summary(errors)
    out.update(
        map="tiled",
        scenes=int(smk.wildcards.n),
        cities=int(maps["city"].nunique()),
        objects=int(round(maps.groupby("city").size().mean())),
        method=str(errors["method"].iloc[0]),
        index_mb=float(np.mean([b["bytes"] for b in built]) / 1e6) if built else float("nan"),
        index_build_s=float(np.mean([b["cpu_s"] for b in built])) if built else float("nan"),
    )
    io.write_parquet(errors, smk.output.errors, {"method": method, "split": split, "search": cfg.to_dict()})
    io.write_json(evaluation.json_safe(out), smk.output.summary)
    log.info("summary: %s", out)


runlog.run(main, snakemake)  # noqa: F821
