# Images branch: a folder of geotagged crowd images -> audit -> masks -> SfM -> classified points.


rule fetch_images:
    output:
        images=directory("resources/images/{scene}"),
    params:
        source=images_fetch_params,
        timeout_s=config["fetch"].get("timeout_s", 30),
    log:
        "logs/fetch_images/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fetch_images.py"


rule images_audit:
    input:
        images=images_dir,
    output:
        table="results/{scene}/images/images.parquet",
    params:
        dedup_threshold=config["images"]["dedup_threshold"],
        missing_gps=config["images"].get("missing_gps", "keep"),
    log:
        "logs/images_audit/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
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
    params:
        backend=config["segment"]["backend"],
        weights=config["segment"].get("weights"),
        labels_dir=config["segment"].get("labels_dir"),
        watermark_box=config["segment"].get("watermark_box"),
    log:
        "logs/segment/{scene}.log",
    benchmark:
        "benchmarks/segment/{scene}.tsv"
    resources:
        mem_mb=4000,
        runtime=30,
    conda:
        "../../envs/flatlandia.yaml"
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
    params:
        options=config["sfm"],
        seed=config["seed"],
    threads: 2
    log:
        "logs/sfm/{scene}.log",
    benchmark:
        "benchmarks/sfm/{scene}.tsv"
    resources:
        mem_mb=8000,
        runtime=120,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/sfm.py"


rule classify_points:
    input:
        model="results/{scene}/sfm/model",
        classes="results/{scene}/segment/classes",
    output:
        points="results/{scene}/sfm/classified_points.parquet",
        ply="results/{scene}/sfm/classified_points.ply",
    log:
        "logs/classify_points/{scene}.log",
    benchmark:
        "benchmarks/classify_points/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
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
