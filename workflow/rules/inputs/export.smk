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


def export_original_sources(wildcards=None):
    """The coarse proposal sources present that the authors' schema has a key for: the coarse models'
    (flatlandia.data.original.SOURCES), not the solver's."""
    return [s for s in export_present_sources() if vocabulary.coarse_source(s) in vocabulary.COARSE_LOSSES]


def export_original_inputs(wildcards):
    """Every benchmark scene's reference map, recovered poses (their theta is the lon/lat one) and
    queries, the coarse proposal tables present that their schema names, and the published local maps."""
    tables = export_coarse_tables()
    return {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "recovered": per_scene(paths.recovered(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
        "proposals": [tables[s] for s in export_original_sources()],
        "local_maps": flatlandia_file("local_maps.json"),
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
#: the export in the authors' form (flatlandia.data.original.FILES)
EXPORT_ORIGINAL_FILES = ["data/flatlandia.json", "data/region_proposal.json", "data/local_maps.json", "README.md"]


def export_products():
    """The `export` target (not in `all`): results/export/ for every benchmark scene, and the
    benchmark in the authors' form (results/export/original/)."""
    if not benchmark_scenes():
        return []
    return (
        [paths.export(f) for f in EXPORT_INDEX_FILES]
        + [paths.export(f, scene) for scene in benchmark_scenes() for f in EXPORT_SCENE_FILES]
        + [paths.export_original(f) for f in EXPORT_ORIGINAL_FILES]
    )
