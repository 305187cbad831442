# Input functions and settings of the rules in rules/data.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def fetch_flatlandia_note(wildcards):
    """No input: says in one line that the plan downloads the published data (say_download), while
    no earlier fetch's flag is there."""
    if not Path(FETCH_FLAG).exists():
        url, dest = config["fetch"]["url"], config["fetch"]["dest"]
        say_download("flatlandia", "the published data", "fetch_flatlandia", url, dest, missing_data_folder())
    return []


def fetch_dest(wildcards, output):
    """fetch.dest, where the data is unpacked, beside the fetch's flag (FETCH_FLAG: dest's name with
    .fetched); taken from the flag, as Snakemake asks of a path parameter, so a module's prefix moves both."""
    return str(Path(output.flag).parent / Path(config["fetch"]["dest"]).name)


def reference_map_inputs(wildcards):
    """A published scene's map is built from the published files; an images scene's from its objects."""
    if scene_source(wildcards) == "images":
        return {"objects": paths.objects(wildcards.scene)}
    return {**scene_data_inputs(wildcards), "ingest": paths.ingest(wildcards.scene)}
