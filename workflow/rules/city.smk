# City scale (target `city`, not in `all`): the benchmark scenes tiled into cities of 1-20 scenes,
# an index per city map, today's whole-map solver beside the city search, synthetic cities up to
# 100,000 objects, and the table results/tables/city_scale.{parquet,md}.


include: "inputs/city.smk"


rule city_maps:
    input:
        unpack(city_scene_inputs),
    output:
        map="results/city/{n}/map.parquet",
        queries="results/city/{n}/queries.parquet",
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
        scenes=benchmark_scenes(),
        spacing_m=config["city"]["spacing_m"],
    script:
        "../scripts/city_maps.py"


rule city_index:
    input:
        map="results/city/{n}/map.parquet",
        queries="results/city/{n}/queries.parquet",
    output:
        index=directory("results/city/{n}/index"),
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
        errors="results/city/{n}/errors_{method}.parquet",
        summary="results/city/{n}/summary_{method}.json",
    log:
        "logs/city_eval/{n}_{method}.log",
    benchmark:
        "logs/benchmarks/city_eval/{n}_{method}.tsv"
    wildcard_constraints:
        n="[0-9]+",
        method="|".join(CITY_METHODS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_eval")
    resources:
        **rule_resources("city_eval"),
    params:
        solver=config["solver"],
        split=config["city"]["split"],
        search=config["city"]["search"],
    script:
        "../scripts/city_eval.py"


rule city_calibration:
    input:
        unpack(city_calibration_inputs),
    output:
        calibration=CITY_CALIBRATION,
        answers="results/city/calibration_answers.parquet",
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
        maps=beyond_city_maps(),
        scenes=benchmark_scenes(),
        seed=config["seed"],
        solver=config["solver"],
        search=config["city"]["search"],
        simulate=config["city"]["simulate"],
        spacing_m=config["city"]["spacing_m"],
        beyond=BEYOND_PROTOCOL,
    script:
        "../scripts/city_calibration.py"


rule city_simulate:
    input:
        unpack(city_scene_inputs),
        priors="results/solver/priors/whole.json",
        calibration=CITY_CALIBRATION,
    output:
        errors="results/city/simulated/{objects}/errors.parquet",
        summary="results/city/simulated/{objects}/summary.json",
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
        scenes=benchmark_scenes(),
        seed=config["seed"],
        spacing_m=config["city"]["spacing_m"],
        split=config["city"]["split"],
        solver=config["solver"],
        search=config["city"]["search"],
        simulate=config["city"]["simulate"],
    script:
        "../scripts/city_simulate.py"


rule city_table:
    input:
        summaries=city_summaries(),
    output:
        parquet="results/tables/city_scale.parquet",
        markdown="results/tables/city_scale.md",
    log:
        "logs/city_table/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("city_table")
    resources:
        **rule_resources("city_table"),
    params:
        split=config["city"]["split"],
        spacing_m=config["city"]["spacing_m"],
    script:
        "../scripts/city_table.py"
