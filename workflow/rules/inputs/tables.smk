# Input functions and settings of the rules in rules/tables.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def tokens_files():
    if FLAT_FETCH:
        return [FETCH_FLAG]
    return [p for p in per_scene(str(FLAT_ROOT / "maps/{scene}/tokens.txt"), benchmark_scenes()) if Path(p).exists()]


def result_tables():
    """Every result table of the run (Parquet); `snakemake tables` builds just these."""
    return [p for p in products_of_the_run() if Path(p).parent == Path(paths.tables_dir()) and p.endswith(".parquet")]
