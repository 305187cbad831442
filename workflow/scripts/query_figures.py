"""Rule query_figures: a figure per test query of one scene and a gallery of its worst queries."""

from flatlandia.plumbing import files, rule_log
from flatlandia.report import figures
from flatlandia.viewer import query_figures, scene_view


def main(smk, log):
    errors = dict(zip(smk.params.runs, smk.input.errors))
    view = scene_view.read_view(smk.wildcards.scene, smk.input.reference_map, smk.input.queries, errors)
    with files.atomic_dir(smk.output.figures) as folder:
        written = query_figures.write_query_figures(view, folder)
    figures.save(query_figures.worst_figure(view), smk.output.worst)
    log.info("scene %s: %d query figures, featured runs %s", view.scene, len(written), list(view.featured))


rule_log.run(main, snakemake)  # noqa: F821
