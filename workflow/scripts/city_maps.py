"""Rule city_maps: the benchmark scenes cut into cities of {n} scenes, each tiled into one map.

Writes every city's reference map and queries in one table each (column ``city``: the city's
number); see flatlandia.city.tiling.
"""

import pandas as pd

from flatlandia.city import tiling
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    refs = {s: pd.read_parquet(p) for s, p in zip(smk.params.scene_ids, smk.input.reference_maps)}
    qs = {s: pd.read_parquet(p) for s, p in zip(smk.params.scene_ids, smk.input.queries)}
    maps, queries = [], []
    for k, group in enumerate(tiling.groups(list(smk.params.scene_ids), int(smk.wildcards.n))):
        ref, q = tiling.tile([refs[s] for s in group], [qs[s] for s in group], float(smk.params["city.spacing_m"]))
        maps.append(ref.drop(columns=["geometry"], errors="ignore").assign(city=k))
        queries.append(q.assign(city=k))
        log.info("city %d: scenes %s, %d objects, %d queries", k, group, len(ref), len(q))
    meta = {"scenes_per_city": int(smk.wildcards.n), "spacing_m": float(smk.params["city.spacing_m"])}
    files.write_parquet(pd.concat(maps, ignore_index=True), smk.output.map, meta)
    files.write_parquet(pd.concat(queries, ignore_index=True), smk.output.queries, meta)


rule_log.run(main, snakemake)  # noqa: F821
