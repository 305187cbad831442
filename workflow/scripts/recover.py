"""Rule recover: register each GT local map onto the reference map (pose + matched objects)."""

import time
from pathlib import Path

from flatlandia.classes import CLASSES
from flatlandia.data import published, recover
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scene = smk.wildcards.scene
    root = Path(smk.params.root)
    lonlat, classes = published.read_reference_map(root / f"individual_reference_maps/map_{scene}.json", len(CLASSES))
    local = published.read_local_maps(root / "local_maps.json", scene)
    t0 = time.perf_counter()
    rec = recover.recover_scene(
        scene,
        lonlat,
        classes,
        local,
        tol_m=smk.params["recover.tol_m"],
        progress=rule_log.progress(log, f"recover scene {scene}"),
    )
    dt = time.perf_counter() - t0
    files.write_parquet(
        rec, smk.output.recovered, {"scene": scene, "tol_m": smk.params["recover.tol_m"], "seconds": dt}
    )
    ok = rec["recovered"].sum()
    log.info(
        "scene %s: %d/%d queries recovered in %.3f s; max residual %.2e m; ambiguous %d (%s)",
        scene,
        ok,
        len(rec),
        dt,
        rec["residual_m"].max(),
        rec["ambiguous"].sum(),
        rec["resolution"].value_counts().to_dict(),
    )


rule_log.run(main, snakemake)  # noqa: F821
