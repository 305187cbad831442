# Input functions of the rules in rules/external.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules. external_methods() and external_runs() sit in
# inputs/fine.smk, where fine_runs() lists the external runs as the fine rules are parsed.
import re


def external_method_pattern():
    """The external methods' names as a wildcard constraint (one that matches nothing without any)."""
    names = [e["name"] for e in external_methods()]
    return "|".join(map(re.escape, names)) if names else "(?!x)x"


def external_poses(method):
    """An external method's poses file (config external[].poses, relative to the working folder,
    else to the repository)."""
    entry = next(e for e in external_methods() if e["name"] == method)
    return str(config_path(entry["poses"]))


def external_eval_inputs(wildcards):
    """The poses file, the benchmark scenes' maps and queries, and for coarse proposals their table."""
    inp = {
        "poses": external_poses(wildcards.method),
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
    }
    if vocabulary.coarse_source(wildcards.proposal):
        inp["coarse"] = paths.proposal_table(wildcards.proposal)
    return inp
