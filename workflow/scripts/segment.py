"""Rule segment: label maps -> pycolmap masks (<image>.png, 0 = ignore) and object-class maps."""

from pathlib import Path

import pandas as pd
from PIL import Image

from flatlandia.images import segment
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    table = pd.read_parquet(smk.input.table)
    names = list(table.loc[table["kept"], "name"])
    p = smk.params
    backend = segment.make_backend(
        p["segment.backend"], p["segment.weights"], p["segment.labels_dir"], device=smk.config["device"]
    )
    log.info("backend %s on %d images", backend.name, len(names))
    if backend.name == "transformers":
        missing = segment.missing_classes(backend.names)
        log.info("Flatlandia classes the checkpoint cannot produce: %s", ", ".join(missing) or "none")
    rows = []
    with files.atomic_dir(smk.output.masks) as masks, files.atomic_dir(smk.output.classes) as classes:
        for name in rule_log.progress(log, "segment")(names):
            ids, labels = backend.labels(Path(smk.input.images) / name)
            mask, cls, shares = segment.mask_and_classes(
                ids, labels, p["segment.watermark_box"], p["segment.dilate_px"]
            )
            Image.fromarray(mask).save(masks / f"{name}.png")
            Image.fromarray(cls).save(classes / f"{name}.png")
            rows.append({"name": name, "backend": backend.name, **shares})
    df = pd.DataFrame(rows)
    files.write_parquet(df, smk.output.stats)
    log.info("mean masked share %.3f, object pixels %.4f", df["masked"].mean(), df["objects"].mean())


rule_log.run(main, snakemake)  # noqa: F821
