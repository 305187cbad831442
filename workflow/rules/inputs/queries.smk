# Input functions and settings of the rules in rules/queries.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def queries_gpus(wildcards):
    """GPUs for a queries job with config device: cuda (rules/resources.yaml): 1 for an images scene
    whose depth maps come from the transformers backend, none otherwise (no model)."""
    images = scene_source(wildcards) == "images"
    return 1 if images and config["images"]["depth"]["backend"] == "transformers" else 0


def queries_inputs(wildcards):
    """Published scenes: the recovered published local maps; images scenes: the GPS-aligned SfM
    model, the objects its points belong to and the photos (their depth maps)."""
    s = wildcards.scene
    if scene_source(wildcards) == "images":
        return {
            "model": paths.sfm(s, "model"),
            "alignment": paths.gps_alignment(s),
            "objects": paths.objects(s),
            "members": paths.point_objects(s),
            "reference_map": paths.reference_map(s),
            "images": images_dir(wildcards),
        }
    return {
        **scene_data_inputs(wildcards),
        "recovered": paths.recovered(s),
        "reference_map": paths.reference_map(s),
    }


def images_scene_reads(wildcards):
    """The config keys of section images an images scene's queries read; none for a published scene."""
    if scene_source(wildcards) != "images":
        return set()
    return {"images.min_objects", "images.min_points", "images.depth"}
