# Beyond one frame: a GPS fix and sequences of frames (flatlandia.sequences), on each scene's whole
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
        errors=paths.beyond_scene(part="errors"),
        summary=paths.beyond_scene(),
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
        **config_keys("seed", "solver", "beyond", exclude=BEYOND_CITIES),
        scene_ids=benchmark_scenes(),
    script:
        "../scripts/beyond_scene.py"


rule beyond_city:
    input:
        unpack(beyond_city_inputs),
    output:
        errors=paths.beyond_city(part="errors.parquet"),
        summary=paths.beyond_city(),
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
        **config_keys(
            "seed", "solver", "city.search", "city.simulate", "city.spacing_m", "beyond", exclude=BEYOND_CITIES
        ),
        scene_ids=benchmark_scenes(),
    script:
        "../scripts/beyond_city.py"


rule beyond_table:
    input:
        summaries=beyond_summaries,
        errors=beyond_errors,
    output:
        parquet=paths.table("beyond_{part}"),
        markdown=paths.table("beyond_{part}", "md"),
        risk_coverage=report(
            paths.figure("beyond_{part}_risk_coverage.png"),
            caption="../report/risk_coverage.rst",
            category="Knowing when it is right",
        ),
        reliability=report(
            paths.figure("beyond_{part}_reliability.png"),
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
        **config_keys("beyond.split", "beyond", "solver.answer_probability", exclude=BEYOND_CITIES),
    script:
        "../scripts/beyond_table.py"
