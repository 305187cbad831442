# Input functions and settings of the rules in rules/objects.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def objects_inputs(wildcards):
    """Published scenes: the class cloud (+ the other scenes' maps for label transfer); images
    scenes: the classified SfM points, their image instances and the GPS alignment."""
    s = wildcards.scene
    if scene_source(wildcards) == "images":
        return {
            "points": paths.classified_points(s),
            "instances": paths.point_instances(s),
            "alignment": paths.gps_alignment(s),
        }
    return {
        "cloud": flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
        "reference_map": flatlandia_file(f"individual_reference_maps/map_{s}.json"),
        # label transfer uses the class labels of the *other* scenes' maps
        "other_maps": [
            flatlandia_file(f"individual_reference_maps/map_{o}.json") for o in benchmark_scenes() if o != s
        ],
    }


def principal_plane_inputs(wildcards):
    s = wildcards.scene
    return {
        "cloud": flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
        # after ingest has checked the published files: a broken transformations.json is then one
        # ERROR line (ingest's), not two from jobs running side by side
        "ingest": paths.ingest(s),
    }


def audit_inputs(wildcards):
    scenes = class_cloud_scenes(benchmark_scenes())
    return {
        "objects": [paths.objects(s) for s in scenes],
        "clouds": [flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply") for s in scenes],
        "transformations": [flatlandia_file(f"maps/{s}/transformations.json") for s in scenes],
        "reference_maps": [flatlandia_file(f"individual_reference_maps/map_{s}.json") for s in scenes],
    }
