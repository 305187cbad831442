# The benchmark's inputs as plain files (target `export`, not in `all`): per benchmark scene its
# reference map, frame, queries and their local maps, the proposals, and apart the ground truth;
# beside them the classes, the scenes, a README and the template of the poses a method fills to
# be scored (flatlandia.export; README "Export the benchmark"). No lambdas in rules.


include: "inputs/export.smk"


rule export_scene:
    input:
        unpack(export_scene_inputs),
    output:
        reference_map="results/export/{scene}/reference_map.csv",
        reference_geojson="results/export/{scene}/reference_map.geojson",
        frame="results/export/{scene}/frame.json",
        queries="results/export/{scene}/queries.csv",
        local_maps="results/export/{scene}/local_maps.csv",
        proposals="results/export/{scene}/proposals.csv",
        ground_truth="results/export/{scene}/ground_truth.csv",
        query_cameras="results/export/{scene}/query_cameras.geojson",
    log:
        "logs/export_scene/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("export_scene")
    resources:
        **rule_resources("export_scene"),
    params:
        sources=export_present_sources,
    script:
        "../scripts/export_scene.py"


rule export_index:
    input:
        unpack(export_index_inputs),
    output:
        readme="results/export/README.md",
        classes="results/export/classes.csv",
        scenes="results/export/scenes.csv",
        template="results/export/poses_template.csv",
    log:
        "logs/export_index/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("export_index")
    resources:
        **rule_resources("export_index"),
    params:
        scenes=benchmark_scenes(),
        cities=benchmark_cities(),
        sources=export_present_sources,
    script:
        "../scripts/export_index.py"
