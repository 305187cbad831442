"""Rule coarse_target: the neighbourhood similarity target S of every (query, reference object) of a scene.

Cached as Parquet (columns scene, token, obj_idx, S, d_p, d_s, n_matched); the settings and the
measured time per query go into the file's metadata.
"""

import time

import pandas as pd

from flatlandia.coarse import target
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    cfg = target.SimilarityConfig.from_dict(smk.params["coarse.similarity"])
    ref = pd.read_parquet(smk.input.reference_map)
    queries = pd.read_parquet(smk.input.queries)
    scene = str(smk.wildcards.scene)
    log.info("scene %s: %d objects, %d queries, %s", scene, len(ref), len(queries), cfg.to_dict())
    t0 = time.perf_counter()
    table = target.scene_similarity(ref, queries, cfg, progress=rule_log.progress(log, f"similarity {scene}"))
    seconds = time.perf_counter() - t0
    meta = {
        "scene": scene,
        "config": cfg.to_dict(),
        "seconds": seconds,
        "per_query_ms": 1000 * seconds / max(len(queries), 1),
        "map_type": "gt",
        "definition": "S = (1 - d_p) (1 - d_s); see flatlandia.coarse.target",
    }
    files.write_parquet(table, smk.output.similarity, meta)
    log.info(
        "scene %s: %d rows in %.2f s (%.1f ms per query), mean S %.3f",
        scene,
        len(table),
        seconds,
        meta["per_query_ms"],
        float(table["S"].mean()) if len(table) else float("nan"),
    )


rule_log.run(main, snakemake)  # noqa: F821
