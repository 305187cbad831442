# City scale (target `city`, not in `all`): the benchmark scenes tiled into cities of 1-20 scenes,
# an index per city map, today's whole-map solver beside the city search, synthetic cities up to
# 100,000 objects, and the table results/tables/city_scale.{parquet,md}.


include: "inputs/city.smk"


rule city_maps:
    input:
        unpack(city_scene_inputs),
    output:
        map=paths.city(),
        queries=paths.city(part="queries.parquet"),
    log:
        "logs/city_maps/{n}.log",
    wildcard_constraints:
        n="[0-9]+",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_maps")
    resources:
        **rule_resources("city_maps"),
    params:
        **config_keys("city.spacing_m"),
        scene_ids=benchmark_scenes(),
    script:
        "../scripts/city_maps.py"


rule city_index:
    input:
        map=paths.city(),
        queries=paths.city(part="queries.parquet"),
    output:
        index=directory(paths.city(part="index")),
    log:
        "logs/city_index/{n}.log",
    wildcard_constraints:
        n="[0-9]+",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_index")
    resources:
        **rule_resources("city_index"),
    script:
        "../scripts/city_index.py"


rule city_eval:
    input:
        unpack(city_eval_inputs),
    output:
        errors=paths.city_result(part="errors"),
        summary=paths.city_result(),
    log:
        "logs/city_eval/{n}_{method}.log",
    benchmark:
        "logs/benchmarks/city_eval/{n}_{method}.tsv"
    wildcard_constraints:
        n="[0-9]+",
        method="|".join(vocabulary.CITY_METHODS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_eval")
    resources:
        **rule_resources("city_eval"),
    params:
        **config_keys("solver", "city.split", "city.search"),
    script:
        "../scripts/city_eval.py"


rule city_calibration:
    input:
        unpack(city_calibration_inputs),
    output:
        calibration=CITY_CALIBRATION,
        answers=paths.city_calibration("calibration_answers.parquet"),
    log:
        "logs/city_calibration/all.log",
    benchmark:
        "logs/benchmarks/city_calibration/all.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_calibration")
    resources:
        **rule_resources("city_calibration"),
    params:
        **config_keys(
            "seed", "solver", "city.search", "city.simulate", "city.spacing_m", "beyond", exclude=BEYOND_CITIES
        ),
        maps=beyond_city_maps(),
        scene_ids=benchmark_scenes(),
    script:
        "../scripts/city_calibration.py"


rule city_simulate:
    input:
        unpack(city_scene_inputs),
        priors=paths.solver_priors(vocabulary.WHOLE),
        calibration=CITY_CALIBRATION,
    output:
        errors=paths.simulated_city(part="errors.parquet"),
        summary=paths.simulated_city(),
    log:
        "logs/city_simulate/{objects}.log",
    benchmark:
        "logs/benchmarks/city_simulate/{objects}.tsv"
    wildcard_constraints:
        objects="[0-9]+",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_simulate")
    resources:
        **rule_resources("city_simulate"),
    params:
        **config_keys("seed", "city.spacing_m", "city.split", "solver", "city.search", "city.simulate"),
        scene_ids=benchmark_scenes(),
    script:
        "../scripts/city_simulate.py"


rule city_table:
    input:
        summaries=city_summaries(),
    output:
        parquet=paths.table("city_scale"),
        markdown=paths.table("city_scale", "md"),
    log:
        "logs/city_table/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_table")
    resources:
        **rule_resources("city_table"),
    params:
        **config_keys("city.split", "city.spacing_m"),
    script:
        "../scripts/city_table.py"
