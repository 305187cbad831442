"""Rule dataset_stats: the paper's Table 2 recomputed per scene, per city and overall."""

from pathlib import Path

import pandas as pd

from flatlandia.data import stats
from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    cities = smk.params.cities
    tokens_of = {Path(p).parent.name: Path(p) for p in smk.input.tokens if Path(p).name == "tokens.txt"}
    for flag in (Path(p) for p in smk.input.tokens if p.endswith(".fetched")):  # data fetched by the workflow
        root = Path(flag.read_text().strip())
        tokens_of.update({t.parent.name: t for t in root.glob("maps/*/tokens.txt")})
    rows, lonlat_by_city = [], {}
    for ref_path, q_path in zip(smk.input.reference_maps, smk.input.queries):
        ref, q = pd.read_parquet(ref_path), pd.read_parquet(q_path)
        scene = str(ref["scene"].iloc[0])
        tokens = tokens_of.get(scene)
        n_images = len(tokens.read_text().split()) if tokens else None
        rows.append(stats.scene_stats(scene, cities[scene], ref, q, n_images))
        lonlat_by_city.setdefault(cities[scene], {})[scene] = ref[["lon", "lat"]].to_numpy()
    per_scene = pd.DataFrame(rows)
    union = {c: stats.union_area_km2(d) for c, d in lonlat_by_city.items()}
    union["all"] = sum(union.values())  # cities do not overlap
    table = stats.city_table(per_scene, union)
    files.write_parquet(per_scene, smk.output.per_scene)
    tables.write_table(
        table,
        "dataset_stats",
        smk.output.parquet,
        smk.output.markdown,
        smk.output.latex,
        title="Dataset statistics (paper Table 2)",
        note="Per city: mean per scene of area (convex hull of the objects, km2), map size (kB, compact JSON), "
        "images (SfM tokens), objects and queries; density = objects per 1000 m2. `paper_*`: the paper's "
        "figures.",
    )
    log.info("\n%s", tables.to_markdown(table))


rule_log.run(main, snakemake)  # noqa: F821
