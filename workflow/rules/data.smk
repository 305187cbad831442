# Data source: the published Flatlandia data, checked per scene; every scene's reference map.


include: "inputs/data.smk"


if FLAT_FETCH:

    rule fetch_flatlandia:
        input:
            fetch_flatlandia_note,
        output:
            flag=FETCH_FLAG,
        log:
            "logs/fetch_flatlandia/fetch.log",
        conda:
            "../envs/flatlandia.yaml"
        params:
            **config_keys("fetch", exclude=["fetch.dest"]),
            dest=fetch_dest,
            data_folder=str(FLAT_ROOT_GIVEN),
            scene_sheet=str(config_path(config["scenes"])),
        script:
            "../scripts/fetch_flatlandia.py"


rule ingest:
    input:
        unpack(scene_data_inputs),
    output:
        report=paths.ingest(),
    log:
        "logs/ingest/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("ingest")
    resources:
        **rule_resources("ingest"),
    params:
        **config_keys("ingest.verify_sha256"),
        root=str(FLAT_ROOT),
    script:
        "../scripts/ingest.py"


rule reference_map:
    input:
        unpack(reference_map_inputs),
    output:
        parquet=paths.reference_map(),
        geojson=paths.reference_map(ext="geojson"),
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
