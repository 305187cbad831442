"""Rule beyond_table: results/tables/beyond_{part}.{parquet,md}, the rows of rule beyond_scene
(`one_frame`) and of beyond_city too (`one_frame_city`) (flatlandia.sequences.sequence_table), and the answers'
risk-coverage and reliability figures of the same rows (flatlandia.sequences.sequence_figures)."""

import json
from pathlib import Path

import pandas as pd

from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables
from flatlandia.sequences import sequence_figures, sequence_table


def main(smk, log):
    rows = [r for p in smk.input.summaries for r in json.loads(Path(p).read_text())]
    df = sequence_table.table(rows)
    note = sequence_table.note(smk.params["beyond.split"], dict(smk.params["beyond"]))
    tables.write_table(df, "beyond_one_frame", smk.output.parquet, note=note)  # schema-checked
    text = sequence_table.markdown(df, note)
    files.write_text(text, smk.output.markdown)
    log.info("\n%s", text)
    errors = (
        pd.concat([pd.read_parquet(p) for p in smk.input.errors], ignore_index=True)
        if smk.input.errors
        else pd.DataFrame()
    )
    sequence_figures.plot_risk_coverage(
        errors, float(smk.params["solver.answer_probability"]), smk.output.risk_coverage
    )
    sequence_figures.plot_reliability(errors, smk.output.reliability)


rule_log.run(main, snakemake)  # noqa: F821
