"""Rule fetch_flatlandia: download the published data when no local copy is configured."""

import pandas as pd

from flatlandia.data import fetch
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scenes = pd.read_csv(smk.params.scene_sheet, sep="\t", dtype=str, keep_default_na=False)
    scenes = scenes[scenes["source"] == "flatlandia"]
    cfg = smk.params["fetch"]
    log.info("fetching %s into %s", cfg["url"], smk.params.dest)
    log.info("pinned sha256: %s; settings %s", cfg["sha256"] or "none", cfg)
    if fetch.fetched_before(smk.params.dest):  # only a folder this run's fetch wrote, unchanged, is replaced
        log.info("replacing the earlier fetch in %s", smk.params.dest)
    try:
        dest = fetch.fetch_flatlandia(
            smk.params.dest,
            scenes,
            cfg["url"],
            cfg["timeout_s"],
            sha256=cfg["sha256"],
            limits=fetch.Limits.from_config(cfg),
            data_folder=smk.params.data_folder,
        )
    except fetch.FetchError as e:
        # say why it fetched: a mistyped flatlandia_root looks like a missing download otherwise
        line = (
            f"the data folder {smk.params.data_folder} (flatlandia_root) does not exist, so the data was fetched: {e}"
        )
        log.error("%s", line)
        raise SystemExit(f"ERROR: {line}") from None
    files.write_text(f"{dest}\n", smk.output.flag)
    log.info("done: %s", dest)


rule_log.run(main, snakemake)  # noqa: F821
