"""Rule availability_table: which published files each scene has (and whether they check out)."""

import json

import pandas as pd

from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    rows = []
    for path in smk.input.reports:
        rep = json.loads(open(path).read())
        rows.append({"scene": rep["scene"], "queries": rep["n_queries"], **rep["available"]})
    df = pd.DataFrame(rows)
    files.write_parquet(df, smk.output.parquet)
    files.write_text("# Published files available per scene\n\n" + tables.to_markdown(df), smk.output.markdown)
    log.info("\n%s", tables.to_markdown(df))


rule_log.run(main, snakemake)  # noqa: F821
