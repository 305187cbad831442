"""Rule manifest: every artifact with its producing rule, input hashes, config hash and commit."""

from flatlandia.plumbing import files, provenance, rule_log


def main(smk, log):
    from pathlib import Path

    df = provenance.manifest()
    df = df[[Path(a).exists() for a in df["artifact"]]].reset_index(drop=True)  # drop records of deleted outputs
    missing = sorted(set(map(str, smk.input)) - set(df["artifact"]))
    if missing:
        log.warning(
            "%d artifacts have no provenance record (produced before records existed?): %s", len(missing), missing[:5]
        )
    files.write_parquet(df, smk.output.parquet)
    log.info("%d artifacts from %d rules", len(df), df["rule"].nunique())


rule_log.run(main, snakemake)  # noqa: F821
