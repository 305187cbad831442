# Input functions of the rules in rules/beyond.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules.


def beyond_scene_inputs(wildcards=None):
    """The benchmark scenes' reference maps and queries, and the solver's learned priors."""
    return {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        "queries": per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
        "priors": "results/solver/priors/whole.json",
    }


def beyond_city_inputs(wildcards):
    """A tiled city's map, queries and index (`city-N`), or the scenes a simulated city is drawn
    from (`simulated-N`, as rule city_simulate); the solver's learned priors."""
    kind, n = wildcards.map.split("-")
    inp = {"priors": "results/solver/priors/whole.json"}
    if kind == "city":
        inp.update(
            map=f"results/city/{n}/map.parquet",
            queries=f"results/city/{n}/queries.parquet",
            index=f"results/city/{n}/index",
        )
    else:
        inp.update(city_scene_inputs())
    return inp


def beyond_scene_priors():
    """The scene rows' camera priors: `on` and/or `off` (config beyond.scene_camera_prior)."""
    return ["on" if p else "off" for p in dict.fromkeys(config["beyond"]["scene_camera_prior"])]


def beyond_city_maps():
    """The city rows' maps: the tiled city of `beyond.city_scenes` scenes (when the benchmark has
    that many) and the simulated city of `beyond.city_objects` objects (two scenes at least)."""
    scenes = benchmark_scenes()
    maps = []
    if config["beyond"]["city_scenes"] <= len(scenes):
        maps.append(f"city-{config['beyond']['city_scenes']}")
    if len(scenes) >= 2:
        maps.append(f"simulated-{config['beyond']['city_objects']}")
    return maps


def beyond_city_requested():
    """The `city` target (or a city row) was asked for (read when the DAG is built: the targets
    are not known while the workflow is parsed)."""
    settings = getattr(workflow, "dag_settings", None)
    targets = {str(t) for t in (settings.targets if settings is not None else ())}
    return "city" in targets or any(t.startswith("results/beyond/") and "/scene/" not in t for t in targets)


def beyond_summaries(wildcards=None):
    """The table's inputs: the scene rows always, the city rows when `city` asks for them or they
    already exist (so `all` keeps them in the table once `city` has built them). An input function:
    the targets are known once the DAG is built."""
    if not benchmark_scenes():
        return []
    scene = expand("results/beyond/scene/summary_{prior}.json", prior=beyond_scene_priors())
    city = [f"results/beyond/{m}/summary.json" for m in beyond_city_maps()]
    wanted = beyond_city_requested()
    return scene + [c for c in city if wanted or os.path.exists(c)]


def beyond_products():
    """The table (in `all`: the scene rows)."""
    if not benchmark_scenes():
        return []
    return ["results/tables/beyond_one_frame.parquet", "results/tables/beyond_one_frame.md"]


def beyond_city_products():
    """The `city` target's share: the city rows and the table holding them."""
    if not benchmark_scenes():
        return []
    return [f"results/beyond/{m}/summary.json" for m in beyond_city_maps()] + beyond_products()
