# Images branch: a folder of geotagged crowd images -> audit -> masks -> SfM -> classified points.


rule fetch_images:
    output:
        images=directory("resources/images/{scene}"),
    log:
        "logs/fetch_images/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
    params:
        source=images_fetch_params,
        timeout_s=config["fetch"].get("timeout_s", 30),
    script:
        "../scripts/fetch_images.py"


rule images_audit:
    input:
        images=images_dir,
    output:
        table="results/{scene}/images/images.parquet",
    log:
        "logs/images_audit/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
    params:
        dedup_threshold=config["images"]["dedup_threshold"],
        missing_gps=config["images"].get("missing_gps", "keep"),
    script:
        "../scripts/images_audit.py"


rule segment:
    input:
        images=images_dir,
        table="results/{scene}/images/images.parquet",
    output:
        masks=directory("results/{scene}/segment/masks"),
        classes=directory("results/{scene}/segment/classes"),
        stats="results/{scene}/segment/segment_stats.parquet",
    log:
        "logs/segment/{scene}.log",
    benchmark:
        "benchmarks/segment/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        backend=config["segment"]["backend"],
        weights=config["segment"].get("weights"),
        labels_dir=config["segment"].get("labels_dir"),
        watermark_box=config["segment"].get("watermark_box"),
    script:
        "../scripts/segment.py"


rule sfm:
    input:
        images=images_dir,
        table="results/{scene}/images/images.parquet",
        masks="results/{scene}/segment/masks",
    output:
        model=directory("results/{scene}/sfm/model"),
        stats="results/{scene}/sfm/sfm_stats.parquet",
        cameras="results/{scene}/sfm/cameras.parquet",
    log:
        "logs/sfm/{scene}.log",
    benchmark:
        "benchmarks/sfm/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    threads: 2
    resources:
        mem_mb=8000,
        runtime=120,
    params:
        options=config["sfm"],
        seed=config["seed"],
    script:
        "../scripts/sfm.py"


rule classify_points:
    input:
        model="results/{scene}/sfm/model",
        classes="results/{scene}/segment/classes",
    output:
        points="results/{scene}/sfm/classified_points.parquet",
        ply="results/{scene}/sfm/classified_points.ply",
        instances="results/{scene}/sfm/point_instances.parquet",
    log:
        "logs/classify_points/{scene}.log",
    benchmark:
        "benchmarks/classify_points/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    params:
        instances_dir=config["segment"].get("instances_dir"),
    script:
        "../scripts/classify_points.py"


rule plot_sfm:
    input:
        model="results/{scene}/sfm/model",
        cameras="results/{scene}/sfm/cameras.parquet",
        stats="results/{scene}/sfm/sfm_stats.parquet",
    output:
        png=report(
            "results/{scene}/sfm/sfm_summary.png",
            caption="../report/sfm_summary.rst",
            category="SfM",
            labels={"scene": "{scene}"},
        ),
    log:
        "logs/plot_sfm/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/plot_sfm.py"


# ---- back half: GPS alignment -> objects -> reference map -> queries (shares flatlandia.objects)
rule images_align:
    input:
        model="results/{scene}/sfm/model",
        cameras="results/{scene}/sfm/cameras.parquet",
    output:
        json="results/{scene}/align/alignment.json",
    log:
        "logs/images_align/{scene}.log",
    benchmark:
        "benchmarks/images_align/{scene}.tsv"
    wildcard_constraints:
        scene=IMAGES_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        align=config["images"]["align"],
        seed=config["seed"],
    script:
        "../scripts/images_align.py"


rule images_objects:
    input:
        points="results/{scene}/sfm/classified_points.parquet",
        instances="results/{scene}/sfm/point_instances.parquet",
        alignment="results/{scene}/align/alignment.json",
    output:
        parquet="results/{scene}/objects/objects.parquet",
        ply="results/{scene}/objects/objects.ply",
        members="results/{scene}/objects/point_objects.parquet",
    log:
        "logs/images_objects/{scene}.log",
    benchmark:
        "benchmarks/images_objects/{scene}.tsv"
    wildcard_constraints:
        scene=IMAGES_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        cluster=config["objects"]["cluster"],
    script:
        "../scripts/images_objects.py"


rule images_reference_map:
    input:
        objects="results/{scene}/objects/objects.parquet",
    output:
        parquet="results/{scene}/maps/reference_map.parquet",
        geojson="results/{scene}/maps/reference_map.geojson",
    log:
        "logs/images_reference_map/{scene}.log",
    wildcard_constraints:
        scene=IMAGES_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/images_reference_map.py"


rule images_queries:
    input:
        model="results/{scene}/sfm/model",
        alignment="results/{scene}/align/alignment.json",
        objects="results/{scene}/objects/objects.parquet",
        members="results/{scene}/objects/point_objects.parquet",
        reference_map="results/{scene}/maps/reference_map.parquet",
    output:
        queries="results/{scene}/queries/queries.parquet",
    log:
        "logs/images_queries/{scene}.log",
    benchmark:
        "benchmarks/images_queries/{scene}.tsv"
    wildcard_constraints:
        scene=IMAGES_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        min_objects=config["images"]["min_objects"],
        min_points=config["images"]["min_points"],
        depth=config["images"]["depth"],
        images_dir=images_dir,
        seed=config["seed"],
        split=config["split"],
    script:
        "../scripts/images_queries.py"
