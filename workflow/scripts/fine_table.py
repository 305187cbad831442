"""Rule fine_table: every fine run's summary in one schema-checked table, and Tables 4-5 in markdown.

Writes ``results/tables/fine_localization.parquet`` through ``tables.write_table`` (schema
``fine_localization``: Parquet + flat markdown + LaTeX, every column: the paper's thresholds and
the field's recalls) and the paper-style layout (ours beside the paper's Tables 4 and 5, then the
recalls beside OrienterNet's published MGL figures, another task) as ``fine_localization.md``.
"""

import json

import pandas as pd

from flatlandia.benchmark import fine_rows
from flatlandia.fine import fine_table
from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    summaries = [json.loads(open(p).read()) for p in smk.input.summaries]
    df = fine_rows.table_rows(summaries)
    note = (
        "Test split of every scene; errors in true metres (pu: the paper's convention, local-map units x 215). "
        "Learned models train on the train split (best-on-validation weights) with GT-BB proposals, or, for "
        "the rows on coarse proposals, with simulated coarse proposals (GT-BB kept; real and simulated "
        "proposals cut to their densest objects within a radius: see `trained on`); the geometric solver "
        "uses only camera and scale priors from the training split and the raw proposals."
    )
    tables.write_table(
        df,
        "fine_localization",
        smk.output.parquet,
        smk.output.rows_markdown,
        smk.output.latex,
        title="Fine 3DoF localization (Tables 4-5), test split",
        note=note,
    )
    text = fine_table.render_markdown(df, note=note)
    files.write_text(text, smk.output.markdown)
    errors = {
        json.loads(open(s).read())["run"]: pd.read_parquet(e) for s, e in zip(smk.input.summaries, smk.input.errors)
    }
    scenes = fine_table.per_scene_rows(df, errors)
    tables.write_table(scenes, "fine_per_scene", smk.output.per_scene)
    files.write_text(fine_table.per_scene_markdown(scenes), smk.output.per_scene_markdown)
    log.info("\n%s", text)


rule_log.run(main, snakemake)  # noqa: F821
