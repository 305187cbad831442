# Images branch: a folder of geotagged crowd images -> audit -> masks -> SfM -> classified points
# -> GPS alignment. Its objects, reference map and queries come from the rules objects, reference_map
# and queries, which pick the images inputs for an images scene.


include: "inputs/images.smk"


rule fetch_images:
    input:
        fetch_images_note,
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
        **config_keys("fetch", exclude=["fetch.url", "fetch.sha256", "fetch.dest"]),
        source=images_fetch_params,
    script:
        "../scripts/fetch_images.py"


rule image_audit:
    input:
        images=images_dir,
    output:
        table=paths.image_table(),
    log:
        "logs/image_audit/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("image_audit")
    resources:
        **rule_resources("image_audit"),
    params:
        **config_keys(
            "images.dedup_threshold",
            "images.min_side_px",
            "images.max_megapixels",
            "images.missing_gps",
        ),
        **scene_align_keys("images.align.mode"),
        folder_fingerprint=images_folder_fingerprint,
    script:
        "../scripts/image_audit.py"


rule segment:
    input:
        images=images_dir,
        table=paths.image_table(),
    output:
        masks=directory(paths.segment(part="masks")),
        classes=directory(paths.segment(part="classes")),
        stats=paths.segment(part="segment_stats.parquet"),
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
        **config_keys(
            "segment.backend",
            "segment.weights",
            "segment.labels_dir",
            "segment.watermark_box",
            "segment.dilate_px",
        ),
    script:
        "../scripts/segment.py"


rule sfm:
    input:
        images=images_dir,
        table=paths.image_table(),
        masks=paths.segment(part="masks"),
    output:
        model=directory(paths.sfm(part="model")),
        stats=paths.sfm(part="sfm_stats.parquet"),
        cameras=paths.sfm(part="cameras.parquet"),
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
        **config_keys("sfm", "seed"),
    script:
        "../scripts/sfm.py"


rule classify_points:
    input:
        model=paths.sfm(part="model"),
        classes=paths.segment(part="classes"),
    output:
        points=paths.classified_points(),
        ply=paths.classified_points(ext="ply"),
        instances=paths.point_instances(),
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
        **config_keys("segment.instances_dir"),
    script:
        "../scripts/classify_points.py"


rule plot_sfm:
    input:
        model=paths.sfm(part="model"),
        cameras=paths.sfm(part="cameras.parquet"),
        stats=paths.sfm(part="sfm_stats.parquet"),
        alignment=paths.gps_alignment(),
    output:
        png=report(
            paths.sfm(part="sfm_summary.png"),
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
        model=paths.sfm(part="model"),
        cameras=paths.sfm(part="cameras.parquet"),
    output:
        json=paths.gps_alignment(),
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
        **scene_align_keys("images.align"),
        **config_keys("seed"),
    script:
        "../scripts/gps_alignment.py"
