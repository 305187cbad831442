# Beyond one frame: a GPS fix and sequences of frames (flatlandia.beyond), on each scene's whole
# map (rule beyond_scene, in `all`) and in the cities (rule beyond_city, in `city`), and the tables
# results/tables/beyond_one_frame.{parquet,md} (the scene rows, in `all`) and
# results/tables/beyond_one_frame_city.{parquet,md} (the scene and city rows, in `city`): two files,
# so that `all` never reruns the city rows, nor drops them from a table `city` wrote. The table rule
# draws the answers' risk-coverage and reliability figures from the same rows.


include: "inputs/beyond.smk"


rule beyond_scene:
    input:
        unpack(beyond_scene_inputs),
    output:
        errors="results/beyond/scene/errors_{prior}.parquet",
        summary="results/beyond/scene/summary_{prior}.json",
    log:
        "logs/beyond_scene/{prior}.log",
    benchmark:
        "logs/benchmarks/beyond_scene/{prior}.tsv"
    wildcard_constraints:
        prior="on|off",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("beyond_scene")
    resources:
        **rule_resources("beyond_scene"),
    params:
        scenes=benchmark_scenes(),
        seed=config["seed"],
        solver=config["solver"],
        beyond=BEYOND_PROTOCOL,
    script:
        "../scripts/beyond_scene.py"


rule beyond_city:
    input:
        unpack(beyond_city_inputs),
    output:
        errors="results/beyond/{map}/errors.parquet",
        summary="results/beyond/{map}/summary.json",
    log:
        "logs/beyond_city/{map}.log",
    benchmark:
        "logs/benchmarks/beyond_city/{map}.tsv"
    wildcard_constraints:
        map="city-[0-9]+|simulated-[0-9]+",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("beyond_city")
    resources:
        **rule_resources("beyond_city"),
    params:
        scenes=benchmark_scenes(),
        seed=config["seed"],
        solver=config["solver"],
        search=config["city"]["search"],
        simulate=config["city"]["simulate"],
        spacing_m=config["city"]["spacing_m"],
        beyond=BEYOND_PROTOCOL,
    script:
        "../scripts/beyond_city.py"


rule beyond_table:
    input:
        summaries=beyond_summaries,
        errors=beyond_errors,
    output:
        parquet="results/tables/beyond_{part}.parquet",
        markdown="results/tables/beyond_{part}.md",
        risk_coverage=report(
            "results/figures/beyond_{part}_risk_coverage.png",
            caption="../report/risk_coverage.rst",
            category="Knowing when it is right",
        ),
        reliability=report(
            "results/figures/beyond_{part}_reliability.png",
            caption="../report/reliability.rst",
            category="Knowing when it is right",
        ),
    log:
        "logs/beyond_table/{part}.log",
    wildcard_constraints:
        part="one_frame|one_frame_city",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("beyond_table")
    resources:
        **rule_resources("beyond_table"),
    params:
        split=config["beyond"]["split"],
        beyond=BEYOND_PROTOCOL,
        threshold=config["solver"]["answer_probability"],
    script:
        "../scripts/beyond_table.py"
