"""Rule image_audit: metadata of every image, kept or dropped and why."""

from flatlandia.images import image_audit
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    df = image_audit.audit_table(
        smk.input.images,
        smk.params["images.dedup_threshold"],
        smk.params["images.missing_gps"],
        min_side_px=int(smk.params["images.min_side_px"]),
        max_megapixels=float(smk.params["images.max_megapixels"]),
    )
    image_audit.check_alignment_inputs(
        df, smk.input.images, smk.params["images.align.mode"]
    )  # before SfM, not after it
    files.write_parquet(df, smk.output.table)
    log.info(
        "%d images, %d kept; dropped: %s",
        len(df),
        int(df["kept"].sum()),
        df.loc[~df["kept"], "drop_reason"].value_counts().to_dict(),
    )


rule_log.run(main, snakemake)  # noqa: F821
