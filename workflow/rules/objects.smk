# Objects from classified point clouds (published class clouds), principal plane, and the audit against
# the published maps. Input functions live in common.smk.


rule objects:
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    input:
        unpack(objects_inputs),
    output:
        parquet="results/{scene}/objects/objects.parquet",
        ply="results/{scene}/objects/objects.ply",
    params:
        cluster=objects_cluster_params,
    log:
        "logs/objects/{scene}.log",
    benchmark:
        "benchmarks/objects/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/objects.py"


rule align:
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    input:
        unpack(align_inputs),
    output:
        json="results/{scene}/align/alignment.json",
    params:
        max_points=20000,  # subsample for the frame origin (median point)
        ground_scale_m=config["align"]["ground_scale_m"],
        fallback_scale_m=config["align"]["fallback_scale_m"],
        min_ground_points=config["align"]["min_ground_points"],
    log:
        "logs/align/{scene}.log",
    benchmark:
        "benchmarks/align/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/align.py"


rule reproduction_audit:
    input:
        unpack(audit_inputs),
    output:
        parquet="results/tables/reference_map_reproduction.parquet",
        markdown=report("results/tables/reference_map_reproduction.md", caption="../report/reference_map_reproduction.rst",
                        category="Tables"),
        latex="results/tables/reference_map_reproduction.tex",
        png=report("results/tables/reference_map_reproduction.png", caption="../report/reference_map_reproduction.rst",
                   category="Reference maps"),
    params:
        scenes=class_cloud_scenes(),
        radius_m=config.get("objects", {}).get("audit_radius_m", 2.0),
    log:
        "logs/reproduction_audit/all.log",
    benchmark:
        "benchmarks/reproduction_audit/all.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/reproduction_audit.py"
