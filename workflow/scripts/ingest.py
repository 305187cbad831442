"""Rule ingest: check a scene's published files and report what is available."""

import sys

from flatlandia.data import ingest
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    rep = ingest.ingest_scene(smk.params.root, smk.wildcards.scene, verify_hash=smk.params["ingest.verify_sha256"])
    for f in rep["files"]:
        log.info(
            "%-28s %-8s %s",
            f["key"],
            "ok" if f["present"] and not f["problem"] else "MISSING" if not f["present"] else "PROBLEM",
            f["problem"],
        )
    log.info("scene %s: %d queries", rep["scene"], rep["n_queries"])
    for line in ingest.optional_problems(rep):  # on the console too: the run goes on without that file
        log.warning(line)
        print(f"WARNING: {line}", file=sys.stderr)
    files.write_json(rep, smk.output.report)


rule_log.run(main, snakemake)  # noqa: F821
