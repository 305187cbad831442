# Objects from classified points (a published scene's class cloud, an images scene's classified SfM
# points), the principal plane of the published class clouds, and the audit against the published maps.


include: "inputs/objects.smk"


rule objects:
    input:
        unpack(objects_inputs),
    output:
        parquet=paths.objects(),
        ply=paths.objects(ext="ply"),
        members=paths.point_objects(),
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
        **config_keys("objects.cluster"),
        source=scene_source,
    script:
        "../scripts/objects.py"


rule principal_plane:
    input:
        unpack(principal_plane_inputs),
    output:
        json=paths.principal_plane(),
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
        **config_keys(
            "objects.principal_plane.max_points",
            "objects.principal_plane.ground_scale_m",
            "objects.principal_plane.fallback_scale_m",
            "objects.principal_plane.min_ground_points",
        ),
    script:
        "../scripts/principal_plane.py"


rule reproduction_audit:
    input:
        unpack(audit_inputs),
    output:
        parquet=paths.table("reference_map_reproduction"),
        markdown=report(
            paths.table("reference_map_reproduction", "md"),
            caption="../report/reference_map_reproduction.rst",
            category="Tables",
        ),
        latex=paths.table("reference_map_reproduction", "tex"),
        png=report(
            paths.table("reference_map_reproduction", "png"),
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
        **config_keys("objects.audit_radius_m"),
        scene_ids=class_cloud_scenes(benchmark_scenes()),
    script:
        "../scripts/reproduction_audit.py"
