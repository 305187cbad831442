"""Rule fetch_images: an images scene's folder from its public source, when no local copy exists."""

from flatlandia.data import fetch
from flatlandia.plumbing import rule_log


def main(smk, log):
    src, cfg = smk.params.source, smk.params["fetch"]
    log.info("fetching %s (%s) into %s", src["url"], src["subfolder"], smk.output.images)
    log.info("pinned sha256: %s; settings %s", src.get("sha256") or "none", cfg)
    try:
        fetch.fetch_images(
            src["url"],
            src["subfolder"],
            smk.output.images,
            cfg["timeout_s"],
            sha256=src.get("sha256", ""),
            limits=fetch.Limits.from_config(cfg),
        )
    except fetch.FetchError as e:
        log.error("%s", e)
        raise SystemExit(f"ERROR: {e}") from None


rule_log.run(main, snakemake)  # noqa: F821
