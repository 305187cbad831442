# Data source: the published Flatlandia data, checked per scene; every scene's reference map.


include: "inputs/data.smk"


if FLAT_FETCH:

    rule fetch_flatlandia:
        output:
            flag=FETCH_FLAG,
        log:
            "logs/fetch_flatlandia/fetch.log",
        conda:
            "../envs/flatlandia.yaml"
        params:
            dest=fetch_dest,
            url=config["fetch"]["url"],
            sha256=config["fetch"]["sha256"],
            timeout_s=config["fetch"]["timeout_s"],
            limits=FETCH_LIMITS,
            scenes=str(config_path(config["scenes"])),
        script:
            "../scripts/fetch_flatlandia.py"


rule ingest:
    input:
        unpack(scene_data_inputs),
    output:
        report="results/{scene}/ingest/ingest.json",
    log:
        "logs/ingest/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("ingest")
    resources:
        **rule_resources("ingest"),
    params:
        root=str(FLAT_ROOT),
        verify_sha256=config["ingest"]["verify_sha256"],
    script:
        "../scripts/ingest.py"


rule reference_map:
    input:
        unpack(reference_map_inputs),
    output:
        parquet="results/{scene}/maps/reference_map.parquet",
        geojson="results/{scene}/maps/reference_map.geojson",
    log:
        "logs/reference_map/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("reference_map")
    resources:
        **rule_resources("reference_map"),
    params:
        root=str(FLAT_ROOT),
        source=scene_source,
    script:
        "../scripts/reference_map.py"
