# Input functions of the rules in rules/export.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules.
#
# The export trains no model and runs no solver: the coarse proposal tables are its inputs only
# where they exist when the run starts (a fresh folder exports the GT-BB proposals alone; after
# `benchmark` or `all` every source). A table that appears later changes the rules' input, so the
# next `snakemake export` writes the export again with it.


def export_coarse_tables():
    """{proposal: its table} of every coarse proposal of this run (config coarse.losses and the
    solver's), present or not, in the vocabulary's order (flatlandia.data.export.COARSE_SOURCES)."""
    losses = set(coarse_losses())
    return {
        p: paths.proposal_table(p)
        for p in vocabulary.COARSE_PROPOSALS
        if vocabulary.coarse_source(p) in losses or vocabulary.coarse_source(p) not in vocabulary.COARSE_LOSSES
    }


def export_present_sources(wildcards=None):
    """The coarse proposal sources whose table exists now (the export's inputs)."""
    return [s for s, p in export_coarse_tables().items() if Path(p).exists()]


def export_proposal_files(wildcards=None):
    """The tables of export_present_sources(), in the same order."""
    tables = export_coarse_tables()
    return [tables[s] for s in export_present_sources()]


def export_scene_inputs(wildcards):
    """A benchmark scene's reference map and queries, and the coarse proposal tables present."""
    return {
        "reference_map": paths.reference_map(wildcards.scene),
        "queries": paths.queries(wildcards.scene),
        "proposals": export_proposal_files(),
    }


def export_index_inputs(wildcards):
    """Every benchmark scene's reference map and queries (scenes.csv, the template), and the coarse
    proposal tables present (the README says which sources the export holds)."""
    return {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
        "proposals": export_proposal_files(),
    }


EXPORT_SCENE_FILES = [
    "reference_map.csv",
    "reference_map.geojson",
    "frame.json",
    "queries.csv",
    "local_maps.csv",
    "proposals.csv",
    "ground_truth.csv",
]
EXPORT_INDEX_FILES = ["README.md", "classes.csv", "scenes.csv", "poses_template.csv"]


def export_products():
    """The `export` target (not in `all`): results/export/ for every benchmark scene."""
    if not benchmark_scenes():
        return []
    return [paths.export(f) for f in EXPORT_INDEX_FILES] + [
        paths.export(f, scene) for scene in benchmark_scenes() for f in EXPORT_SCENE_FILES
    ]
