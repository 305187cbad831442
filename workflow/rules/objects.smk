# Objects from classified point clouds, alignment, and the audit against the published maps.
# Draft: assumes FLAT_ROOT, flatlandia_file(relpath) and class_cloud_scenes() from common.smk.


def objects_inputs(wildcards):
    s = wildcards.scene
    return {
        "cloud": flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
        "reference_map": flatlandia_file(f"individual_reference_maps/map_{s}.json"),
        # label transfer uses the class labels of the *other* scenes' maps
        "other_maps": [
            flatlandia_file(f"individual_reference_maps/map_{o}.json")
            for o in published_scenes()
            if o != s
        ],
    }


def align_inputs(wildcards):
    s = wildcards.scene
    return {
        "cloud": flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
    }


def objects_cluster_params(wildcards):
    return dict(config.get("objects", {}).get("cluster", {}))


def audit_inputs(wildcards):
    scenes = class_cloud_scenes()
    return {
        "objects": expand("results/{scene}/objects/objects.parquet", scene=scenes),
        "clouds": [flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply") for s in scenes],
        "transformations": [flatlandia_file(f"maps/{s}/transformations.json") for s in scenes],
        "reference_maps": [flatlandia_file(f"individual_reference_maps/map_{s}.json") for s in scenes],
    }


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
        max_points=config.get("align", {}).get("max_points", 20000),
        iterations=config.get("align", {}).get("iterations", 500),
        seed=config.get("seed", 0),
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
