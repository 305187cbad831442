# Input functions of the rules in rules/export.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules.
#
# The export trains no model and runs no solver: the coarse proposal tables are its inputs only
# where they exist when the run starts (a fresh folder exports the GT-BB proposals alone; after
# `benchmark` or `all` every source). A table that appears later changes the rules' input, so the
# next `snakemake export` writes the export again with it.


def export_coarse_tables():
    """{source: proposal table} of every coarse source of this run (config coarse.losses and the
    solver's), present or not, in the order of flatlandia.export.COARSE_SOURCES."""
    order = ["sim", "trip", "simtrip"]
    tables = {f"coarse-{loss}": f"results/coarse/{loss}/proposals.parquet" for loss in order if loss in coarse_losses()}
    tables["coarse-solver"] = "results/coarse/solver/proposals.parquet"
    return tables


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
        "reference_map": f"results/{wildcards.scene}/maps/reference_map.parquet",
        "queries": f"results/{wildcards.scene}/queries/queries.parquet",
        "proposals": export_proposal_files(),
    }


def export_index_inputs(wildcards):
    """Every benchmark scene's reference map and queries (scenes.csv, the template), and the coarse
    proposal tables present (the README says which sources the export holds)."""
    return {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        "queries": per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
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
    return [f"results/export/{f}" for f in EXPORT_INDEX_FILES] + [
        f"results/export/{scene}/{f}" for scene in benchmark_scenes() for f in EXPORT_SCENE_FILES
    ]
