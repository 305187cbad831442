"""Rule city_table: results/tables/city_scale.{parquet,md}, today's solver beside the city
search at every city size, tiled and simulated (flatlandia.city.city_table)."""

import json
from pathlib import Path

from flatlandia.city import city_table
from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    df = city_table.table([json.loads(Path(p).read_text()) for p in smk.input.summaries])
    split, spacing_m = smk.params["city.split"], smk.params["city.spacing_m"]
    note = (
        f"Depth local maps, {split} split, no proposal; CPU per query on one core (index, region "
        "priors and solver for the city search; the solver alone for the whole-map row). `tiled`: the benchmark "
        f"scenes cut into cities of `scenes` consecutive scenes, each tiled {spacing_m:g} m apart "
        "(geometry unchanged, ids unique, training views carried along); `simulated`: each scene among synthetic "
        "tiles (the other scenes mirrored, turned, jittered) up to `objects`. Wrong scene: a pose more than 500 m "
        "off (no pose is counted apart)."
    )
    tables.write_table(df, "city_scale", smk.output.parquet, note=note)  # schema-checked
    text = city_table.markdown(df, note)
    files.write_text(text, smk.output.markdown)
    log.info("\n%s", text)


rule_log.run(main, snakemake)  # noqa: F821
