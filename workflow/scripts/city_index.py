"""Rule city_index: the index of every city of {n} scenes (flatlandia.city.index), one .npz per
city, and what each cost to build (CPU seconds) and weighs (build.json)."""

import time

import pandas as pd

from flatlandia.city import index
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    maps, queries = pd.read_parquet(smk.input.map), pd.read_parquet(smk.input.queries)
    built = []
    with files.atomic_dir(smk.output.index) as out:
        for city, ref in maps.groupby("city", sort=True):
            q = queries[(queries["city"] == city) & (queries["split"] == "train")]
            c0 = time.process_time()
            ix = index.build(ref, q)
            seconds = time.process_time() - c0
            ix.save(out / f"{city}.npz")
            built.append(
                {
                    "city": int(city),
                    "objects": ix.n_objects,
                    "views": len(ix.cam),
                    "bytes": ix.nbytes(),
                    "cpu_s": seconds,
                }
            )
            log.info("city %s: %s", city, built[-1])
        files.write_json(built, out / "build.json")


rule_log.run(main, snakemake)  # noqa: F821
