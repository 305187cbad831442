# Objects from classified points (a published scene's class cloud, an images scene's classified SfM
# points), the principal plane of the published class clouds, and the audit against the published maps.


include: "inputs/objects.smk"


rule objects:
    input:
        unpack(objects_inputs),
    output:
        parquet="results/{scene}/objects/objects.parquet",
        ply="results/{scene}/objects/objects.ply",
        members="results/{scene}/objects/point_objects.parquet",
    log:
        "logs/objects/{scene}.log",
    benchmark:
        "logs/benchmarks/objects/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("objects")
    resources:
        **rule_resources("objects"),
    params:
        source=scene_source,
        cluster=objects_cluster_params,
    script:
        "../scripts/objects.py"


rule principal_plane:
    input:
        unpack(principal_plane_inputs),
    output:
        json="results/{scene}/objects/principal_plane.json",
    log:
        "logs/principal_plane/{scene}.log",
    benchmark:
        "logs/benchmarks/principal_plane/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("principal_plane")
    resources:
        **rule_resources("principal_plane"),
    params:
        max_points=config["objects"]["principal_plane"]["max_points"],
        ground_scale_m=config["objects"]["principal_plane"]["ground_scale_m"],
        fallback_scale_m=config["objects"]["principal_plane"]["fallback_scale_m"],
        min_ground_points=config["objects"]["principal_plane"]["min_ground_points"],
    script:
        "../scripts/principal_plane.py"


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
            caption="../report/reference_map_reproduction_figure.rst",
            category="Reference maps",
        ),
    log:
        "logs/reproduction_audit/all.log",
    benchmark:
        "logs/benchmarks/reproduction_audit/all.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("reproduction_audit")
    resources:
        **rule_resources("reproduction_audit"),
    params:
        scenes=class_cloud_scenes(benchmark_scenes()),
        radius_m=config["objects"]["audit_radius_m"],
    script:
        "../scripts/reproduction_audit.py"
