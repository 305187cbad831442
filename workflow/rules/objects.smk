# Objects from classified point clouds (published class clouds), principal plane, and the audit against
# the published maps. Input functions live in common.smk.


rule objects:
    input:
        unpack(objects_inputs),
    output:
        parquet="results/{scene}/objects/objects.parquet",
        ply="results/{scene}/objects/objects.ply",
    log:
        "logs/objects/{scene}.log",
    benchmark:
        "benchmarks/objects/{scene}.tsv"
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        cluster=objects_cluster_params,
    script:
        "../scripts/objects.py"


rule align:
    input:
        unpack(align_inputs),
    output:
        json="results/{scene}/align/alignment.json",
    log:
        "logs/align/{scene}.log",
    benchmark:
        "benchmarks/align/{scene}.tsv"
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        max_points=20000,  # subsample for the frame origin (median point)
        ground_scale_m=config["align"]["ground_scale_m"],
        fallback_scale_m=config["align"]["fallback_scale_m"],
        min_ground_points=config["align"]["min_ground_points"],
    script:
        "../scripts/align.py"


rule reproduction_audit:
    input:
        unpack(audit_inputs),
    output:
        parquet="results/tables/reference_map_reproduction.parquet",
        markdown=report(
            "results/tables/reference_map_reproduction.md",
            caption="../report/reference_map_reproduction.rst",
            category="Tables",
        ),
        latex="results/tables/reference_map_reproduction.tex",
        png=report(
            "results/tables/reference_map_reproduction.png",
            caption="../report/reference_map_reproduction.rst",
            category="Reference maps",
        ),
    log:
        "logs/reproduction_audit/all.log",
    benchmark:
        "benchmarks/reproduction_audit/all.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    params:
        scenes=class_cloud_scenes(),
        radius_m=config.get("objects", {}).get("audit_radius_m", 2.0),
    script:
        "../scripts/reproduction_audit.py"
