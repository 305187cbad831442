# Images branch: a folder of geotagged crowd images -> audit -> masks -> SfM -> classified points
# -> GPS alignment. Its objects, reference map and queries come from the rules objects, reference_map
# and queries, which pick the images inputs for an images scene.


include: "inputs/images.smk"


rule fetch_images:
    output:
        images=directory("resources/images/{scene}"),
    log:
        "logs/fetch_images/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fetch_images")
    resources:
        **rule_resources("fetch_images"),
    params:
        source=images_fetch_params,
        timeout_s=config["fetch"]["timeout_s"],
        limits=FETCH_LIMITS,
    script:
        "../scripts/fetch_images.py"


rule image_audit:
    input:
        images=images_dir,
    output:
        table="results/{scene}/images/images.parquet",
    log:
        "logs/image_audit/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("image_audit")
    resources:
        **rule_resources("image_audit"),
    params:
        dedup_threshold=config["images"]["dedup_threshold"],
        min_side_px=config["images"]["min_side_px"],
        max_megapixels=config["images"]["max_megapixels"],
        missing_gps=config["images"]["missing_gps"],
        align_mode=config["images"]["align"]["mode"],
        folder_fingerprint=images_folder_fingerprint,
    script:
        "../scripts/image_audit.py"


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
        "logs/benchmarks/segment/{scene}.tsv"
    priority: 10
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("segment")
    resources:
        **rule_resources("segment"),
    params:
        backend=config["segment"]["backend"],
        weights=config["segment"]["weights"],
        labels_dir=config["segment"]["labels_dir"],
        watermark_box=config["segment"]["watermark_box"],
        dilate_px=config["segment"]["dilate_px"],
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
        "logs/benchmarks/sfm/{scene}.tsv"
    priority: 10
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("sfm")
    resources:
        **rule_resources("sfm"),
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
        "logs/benchmarks/classify_points/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("classify_points")
    resources:
        **rule_resources("classify_points"),
    params:
        instances_dir=config["segment"]["instances_dir"],
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
        "../envs/flatlandia.yaml"
    threads: rule_threads("plot_sfm")
    resources:
        **rule_resources("plot_sfm"),
    script:
        "../scripts/plot_sfm.py"


rule gps_alignment:
    input:
        model="results/{scene}/sfm/model",
        cameras="results/{scene}/sfm/cameras.parquet",
    output:
        json="results/{scene}/sfm/gps_alignment.json",
    log:
        "logs/gps_alignment/{scene}.log",
    benchmark:
        "logs/benchmarks/gps_alignment/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("gps_alignment")
    resources:
        **rule_resources("gps_alignment"),
    params:
        align=config["images"]["align"],
        seed=config["seed"],
    script:
        "../scripts/gps_alignment.py"
