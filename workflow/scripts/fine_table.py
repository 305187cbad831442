"""Rule fine_table: every fine run's summary in one table, and markdown laid out like Tables 4-5."""

import json

from flatlandia import io, runlog
from flatlandia import fine_eval as fe


def main(smk, log):
    summaries = [json.loads(open(p).read()) for p in smk.input.summaries]
    df = fe.table_rows(summaries)
    io.write_parquet(df, smk.output.parquet, {"runs": [s["run"] for s in summaries]})
    text = fe.render_markdown(df)
    io.write_text(text, smk.output.markdown)
    log.info("\n%s", text)


runlog.run(main, snakemake)  # noqa: F821
