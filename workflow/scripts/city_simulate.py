"""Rule city_simulate: the city search in synthetic cities of {objects} objects.

Each benchmark scene's queries are localized in a city of that scene and synthetic tiles drawn
from the other scenes (flatlandia.city.simulate), indexed as rule city_index does; the index is
built here because these maps exist only for the measurement. Today's solver is not run: its
whole-map search needs a (views x objects) co-visibility matrix, 7 GB at 100,000 objects.
"""

import time

import numpy as np
import pandas as pd

from flatlandia import io, runlog, solver
from flatlandia.city import evaluate, index, search, simulate
from flatlandia.fine import evaluation


def main(smk, log):
    scenes = list(smk.params.scenes)
    refs = {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.reference_maps)}
    qs = {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.queries)}
    templates = {s: simulate.Template(refs[s], qs[s]) for s in scenes}
    learned = solver.LearnedPriors.read(smk.input.priors)
    settings, split, sim = dict(smk.params.solver), smk.params.split, smk.params.simulate
    cfg = search.SearchConfig.from_dict(smk.params.search)
    n_objects = int(smk.wildcards.objects)
    parts, built, sizes, tiles = [], [], [], []
    for k, s in enumerate(scenes):
        if not (qs[s]["split"] == split).any():
            continue
        rng = np.random.default_rng([int(smk.params.seed), k])
        others = [templates[t] for t in scenes if t != s]
        ref, q = simulate.city([refs[s]], [qs[s]], others, n_objects, float(smk.params.spacing_m), sim["jitter_m"], rng)
        c0 = time.process_time()
        ix = index.build(ref, q[q["split"] == "train"])
        built.append((ix.nbytes(), time.process_time() - c0))
        sizes.append(len(ref))
        tiles.append(ref["scene"].nunique())
        parts.append(evaluate.index_errors(ix, q[q["scene"] == s], split, cfg, settings, learned))
        log.info("scene %s: %d objects, %s", s, len(ref), evaluate.summary(parts[-1]))
    errors = pd.concat(parts, ignore_index=True)
    out = evaluate.summary(errors)
    out.update(
        map="simulated",
        scenes=int(round(np.mean(tiles))),
        cities=len(parts),
        objects=int(round(np.mean(sizes))),
        method=str(errors["method"].iloc[0]),
        index_mb=float(np.mean([b for b, _ in built]) / 1e6),
        index_build_s=float(np.mean([c for _, c in built])),
    )
    io.write_parquet(errors, smk.output.errors, {"objects": n_objects, "split": split, "simulate": dict(sim)})
    io.write_json(evaluation.json_safe(out), smk.output.summary)
    log.info("summary: %s", out)


runlog.run(main, snakemake)  # noqa: F821
