"""Rule plot_reference_map: objects by class with the query cameras, as a PNG."""

import pandas as pd

from flatlandia.data import reference_map
from flatlandia.plumbing import files, rule_log, summary


def main(smk, log):
    ref = pd.read_parquet(smk.input.reference_map)
    q = pd.read_parquet(smk.input.queries)
    meta = files.read_parquet_metadata(smk.input.reference_map)
    scene = smk.wildcards.scene
    images = str(meta.get("source", "")).startswith("images")
    reference_map.plot_reference_map(
        ref,
        q,
        smk.output.png,
        f"scene {scene} ({smk.params.city}): {len(ref)} objects, {len(q)} queries",
        axes=reference_map.axis_labels(meta),
        empty_because=summary.EMPTY_MAP_HINT.removeprefix("no objects: ") if images else "",
    )
    log.info("wrote %s", smk.output.png)


rule_log.run(main, snakemake)  # noqa: F821
