# The benchmark's inputs as plain files (target `export`, not in `all`): per benchmark scene its
# reference map, frame, queries and their local maps, the proposals, and apart the ground truth;
# beside them the classes, the scenes, a README and the template of the poses a method fills to
# be scored (flatlandia.data.export); and the benchmark in the authors' own form, for their code
# (flatlandia.data.original; docs/usage.md, "Export the benchmark"). No lambdas in rules.


include: "inputs/export.smk"


rule export_scene:
    input:
        unpack(export_scene_inputs),
    output:
        reference_map=paths.export("reference_map.csv", "{scene}"),
        reference_geojson=paths.export("reference_map.geojson", "{scene}"),
        frame=paths.export("frame.json", "{scene}"),
        queries=paths.export("queries.csv", "{scene}"),
        local_maps=paths.export("local_maps.csv", "{scene}"),
        proposals=paths.export("proposals.csv", "{scene}"),
        ground_truth=paths.export("ground_truth.csv", "{scene}"),
        query_cameras=paths.export("query_cameras.geojson", "{scene}"),
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
        readme=paths.export("README.md"),
        classes=paths.export("classes.csv"),
        scenes=paths.export("scenes.csv"),
        template=paths.export("poses_template.csv"),
    log:
        "logs/export_index/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("export_index")
    resources:
        **rule_resources("export_index"),
    params:
        scene_ids=benchmark_scenes(),
        cities=benchmark_cities(),
        sources=export_present_sources,
    script:
        "../scripts/export_index.py"


# The benchmark in the authors' own form (flatlandia.data.original): their flatlandia.json and
# region_proposal.json regenerated, the published local_maps.json of these queries, a README.
rule export_original:
    input:
        unpack(export_original_inputs),
    output:
        flatlandia=paths.export_original("data/flatlandia.json"),
        region_proposal=paths.export_original("data/region_proposal.json"),
        local_maps=paths.export_original("data/local_maps.json"),
        readme=paths.export_original("README.md"),
    log:
        "logs/export_original/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("export_original")
    resources:
        **rule_resources("export_original"),
    params:
        scene_ids=benchmark_scenes(),
        sources=export_original_sources,
    script:
        "../scripts/export_original.py"
