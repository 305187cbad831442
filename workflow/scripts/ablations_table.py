"""Rule ablations_table: results/tables/ablations.{parquet,md} (each ablation run of the fine stage
beside the run it ablates, the fine table's schema) and ablations_one_frame.parquet (the sequence
and fix protocol's scene rows with the camera prior on and off, the beyond table's schema)."""

import json
from pathlib import Path

from flatlandia.benchmark import fine_rows
from flatlandia.fine import fine_table
from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables
from flatlandia.sequences import sequence_table


def _below(markdown: str) -> str:
    """A table's Markdown one heading level down (its sections under the page's title)."""
    return "\n".join("#" + line if line.startswith("#") else line for line in markdown.splitlines()) + "\n"


def main(smk, log):
    fine = fine_rows.table_rows([json.loads(Path(p).read_text()) for p in smk.input.summaries])
    tables.write_table(fine, "fine_localization", smk.output.fine)
    rows = [r for p in smk.input.beyond for r in json.loads(Path(p).read_text())]
    beyond = sequence_table.table(rows)
    tables.write_table(beyond, "beyond_one_frame", smk.output.beyond)
    note = (
        "Not in `all` (target `ablations`): what the results owe to one part. The solver without the training "
        "split's cameras (no camera gate or cost, no co-visibility, no verifier) beside the solver with them, "
        "on the same test queries."
    )
    beyond_note = sequence_table.note(smk.params["beyond.split"], dict(smk.params["beyond"]))
    text = "# Ablations\n\n" + _below(fine_table.render_markdown(fine, note=note))
    text += "\n" + _below(sequence_table.markdown(beyond, beyond_note))
    files.write_text(text, smk.output.markdown)
    log.info("\n%s", text)


rule_log.run(main, snakemake)  # noqa: F821
