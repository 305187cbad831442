# Input functions and settings of the rules in rules/city.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.

CITY_METHODS = ["solver", "index"]


def city_scene_inputs(wildcards=None):
    """The benchmark scenes' reference maps and queries, in the scenes' order (tiles follow it)."""
    return {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        "queries": per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
    }


def city_eval_inputs(wildcards):
    """A city size's maps and queries, the shared priors, and for the city search its indexes."""
    inp = {
        "map": f"results/city/{wildcards.n}/map.parquet",
        "queries": f"results/city/{wildcards.n}/queries.parquet",
        "priors": "results/solver/priors/whole.json",
    }
    if wildcards.method == "index":
        inp["index"] = f"results/city/{wildcards.n}/index"
    return inp


def city_summaries():
    """Every row of the city table: both methods at each tiled size, the search at each simulated
    size (synthetic tiles are drawn from the other scenes: two scenes at least)."""
    scenes = benchmark_scenes()
    sizes = [n for n in config["city"]["scene_counts"] if n <= len(scenes)]
    simulated = config["city"]["simulate"]["objects"] if len(scenes) >= 2 else []
    return expand("results/city/{n}/summary_{method}.json", n=sizes, method=CITY_METHODS) + expand(
        "results/city/simulated/{objects}/summary.json", objects=simulated
    )


def city_products():
    """The `city` target (not in `all`): the city-scale table, and the table beyond_one_frame_city
    (rules/beyond.smk)."""
    if not benchmark_scenes():
        return []
    return ["results/tables/city_scale.parquet", "results/tables/city_scale.md"] + beyond_city_products()
