"""Rule viewer: a self-contained HTML map viewer of one scene."""

from flatlandia.plumbing import rule_log
from flatlandia.viewer import page, scene_view


def main(smk, log):
    errors = dict(zip(smk.params.runs, smk.input.errors))
    view = scene_view.read_view(smk.wildcards.scene, smk.input.reference_map, smk.input.queries, errors)
    photo = page.MAPILLARY_PHOTO if smk.params.source == "flatlandia" else None  # published: Mapillary keys
    size = page.write_page(view, smk.output.html, photo)
    log.info(
        "scene %s: %d objects, %d queries, %d runs; %s: %.1f kB",
        view.scene,
        len(view.ref),
        len(view.queries),
        len(view.runs),
        smk.output.html,
        size / 1000,
    )


rule_log.run(main, snakemake)  # noqa: F821
