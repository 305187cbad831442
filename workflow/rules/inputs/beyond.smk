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


#: what the beyond rules read of config `beyond`: the protocol and the solver's settings, not which
#: cities the city rows use (those name the rules' outputs), so another city does not rerun them
BEYOND_PROTOCOL = {k: v for k, v in config["beyond"].items() if k not in ("city_scenes", "city_objects")}


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


def beyond_summaries(wildcards):
    """The table's inputs: the scene rows, and for `beyond_one_frame_city` the city rows too."""
    if not benchmark_scenes():
        return []
    scene = expand("results/beyond/scene/summary_{prior}.json", prior=beyond_scene_priors())
    if wildcards.part == "one_frame":
        return scene
    return scene + [f"results/beyond/{m}/summary.json" for m in beyond_city_maps()]


def beyond_errors(wildcards):
    """The figures' inputs: the per-anchor rows of the table's summaries."""
    return [p.replace("summary", "errors").replace(".json", ".parquet") for p in beyond_summaries(wildcards)]


def _beyond_part(part):
    return [
        f"results/tables/beyond_{part}.parquet",
        f"results/tables/beyond_{part}.md",
        f"results/figures/beyond_{part}_risk_coverage.png",
        f"results/figures/beyond_{part}_reliability.png",
    ]


def beyond_products():
    """The table and the answers' figures (in `all`: the scene rows)."""
    if not benchmark_scenes():
        return []
    return _beyond_part("one_frame")


def beyond_city_products():
    """The `city` target's share: the table and the figures with the city rows."""
    if not benchmark_scenes():
        return []
    return _beyond_part("one_frame_city")
