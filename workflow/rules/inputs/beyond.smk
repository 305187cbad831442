# Input functions of the rules in rules/beyond.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules.


def beyond_scene_inputs(wildcards=None):
    """The benchmark scenes' reference maps and queries, and the solver's learned priors."""
    return {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
        "priors": paths.solver_priors(vocabulary.WHOLE),
    }


def beyond_city_inputs(wildcards):
    """A tiled city's map, queries and index (`city-N`), or the scenes a simulated city is drawn
    from (`simulated-N`, as rule city_simulate); the solver's learned priors and the cities'
    map-size correction (rule city_calibration)."""
    kind, n = wildcards.map.split("-")
    inp = {"priors": paths.solver_priors(vocabulary.WHOLE), "calibration": CITY_CALIBRATION}
    if kind == "city":
        inp.update(map=paths.city(n), queries=paths.city(n, "queries.parquet"), index=paths.city(n, "index"))
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


def _beyond_rows(wildcards, kind):
    """The scene rows' files (``summary`` or ``errors``), and for `beyond_one_frame_city` the city rows' too."""
    if not benchmark_scenes():
        return []
    scene = [paths.beyond_scene(prior, kind) for prior in beyond_scene_priors()]
    if wildcards.part == "one_frame":
        return scene
    ext = "json" if kind == "summary" else "parquet"
    return scene + [paths.beyond_city(m, f"{kind}.{ext}") for m in beyond_city_maps()]


def beyond_summaries(wildcards):
    """The table's inputs: the rows' summaries."""
    return _beyond_rows(wildcards, "summary")


def beyond_errors(wildcards):
    """The figures' inputs: the per-anchor rows of the table's summaries."""
    return _beyond_rows(wildcards, "errors")


def _beyond_part(part):
    return [
        paths.table(f"beyond_{part}"),
        paths.table(f"beyond_{part}", "md"),
        paths.figure(f"beyond_{part}_risk_coverage.png"),
        paths.figure(f"beyond_{part}_reliability.png"),
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
