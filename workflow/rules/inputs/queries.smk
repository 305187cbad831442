# Input functions and settings of the rules in rules/queries.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def queries_gpus(wildcards):
    """GPUs for a queries job with config device: cuda (rules/resources.yaml): 1 for an images scene
    whose depth maps come from the transformers backend, none otherwise (no model)."""
    images = scene_source(wildcards) == "images"
    return 1 if images and config["images"]["depth"]["backend"] == "transformers" else 0


def queries_inputs(wildcards):
    """Published scenes: the recovered published local maps; images scenes: the GPS-aligned SfM
    model and the objects its points belong to."""
    s = wildcards.scene
    if scene_source(wildcards) == "images":
        return {
            "model": f"results/{s}/sfm/model",
            "alignment": f"results/{s}/sfm/gps_alignment.json",
            "objects": f"results/{s}/objects/objects.parquet",
            "members": f"results/{s}/objects/point_objects.parquet",
            "reference_map": f"results/{s}/maps/reference_map.parquet",
        }
    return {
        **scene_data_inputs(wildcards),
        "recovered": f"results/{s}/queries/recovered.parquet",
        "reference_map": f"results/{s}/maps/reference_map.parquet",
    }


def queries_images_params(wildcards):
    """Settings of an images scene's queries (config images); none for a published scene."""
    if scene_source(wildcards) != "images":
        return {}
    return {
        "min_objects": config["images"]["min_objects"],
        "min_points": config["images"]["min_points"],
        "depth": config["images"]["depth"],
        "images_dir": images_dir(wildcards),
    }
