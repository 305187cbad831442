# Input functions and settings of the rules in rules/city.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def city_scene_inputs(wildcards=None):
    """The benchmark scenes' reference maps and queries, in the scenes' order (tiles follow it)."""
    return {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
    }


#: the cities' map-size correction of the answers' probability (rule city_calibration), read by
#: every city search (rules city_eval, city_simulate, beyond_city and `flatlandia localize --map`)
CITY_CALIBRATION = paths.city_calibration()


def city_eval_inputs(wildcards):
    """A city size's maps and queries, the shared priors, and for the city search its indexes and
    the map-size correction."""
    n = wildcards.n
    inp = {
        "map": paths.city(n),
        "queries": paths.city(n, "queries.parquet"),
        "priors": paths.solver_priors(vocabulary.WHOLE),
    }
    if wildcards.method == "index":
        inp["index"] = paths.city(n, "index")
        inp["calibration"] = CITY_CALIBRATION
    return inp


def city_calibration_inputs(wildcards=None):
    """The scenes (the simulated city rows' tiles, and a scene map's size), the scene-calibrated
    priors, and each tiled city row's map, queries and index (beyond_city_maps)."""
    inp = {**city_scene_inputs(), "priors": paths.solver_priors(vocabulary.WHOLE)}
    for name in beyond_city_maps():
        kind, n = name.split("-")
        if kind == "city":
            inp.update(
                {
                    f"map_{n}": paths.city(n),
                    f"queries_{n}": paths.city(n, "queries.parquet"),
                    f"index_{n}": paths.city(n, "index"),
                }
            )
    return inp


def city_summaries():
    """Every row of the city table: both methods at each tiled size, the search at each simulated
    size (synthetic tiles are drawn from the other scenes: two scenes at least)."""
    scenes = benchmark_scenes()
    sizes = [n for n in config["city"]["scene_counts"] if n <= len(scenes)]
    simulated = config["city"]["simulate"]["objects"] if len(scenes) >= 2 else []
    tiled = [paths.city_result(n, method) for n in sizes for method in vocabulary.CITY_METHODS]
    return tiled + [paths.simulated_city(objects) for objects in simulated]


def city_products():
    """The `city` target (not in `all`): the city-scale table, and the table beyond_one_frame_city
    (rules/beyond.smk)."""
    if not benchmark_scenes():
        return []
    return [paths.table("city_scale"), paths.table("city_scale", "md")] + beyond_city_products()
