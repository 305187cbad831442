# What each rule asks of a scheduler (cores, memory, time), read from one table,
# workflow/rules/resources.yaml: every rule's threads, mem_mb and runtime (minutes), with the
# measured peak memory and wall time behind them. A rule declares
#     threads: rule_threads("sfm")
#     resources:
#         **rule_resources("sfm"),
# An entry that names a function instead of a number is that function of the stage's inputs file
# (SfM's threads and segment's memory from the config, the trainings' runtimes from their epochs),
# called now when it takes no argument, else handed to Snakemake, which calls it per job.
# A row's optional `gpu` is how many GPUs its jobs ask for when config `device` is cuda (the SLURM
# plugin's `gpu` resource, sbatch --gpus); with auto or cpu no job asks for one.
# Sites change a figure for themselves in their profile (set-resources, set-threads), not here.
import inspect

import yaml

RESOURCE_KEYS = ("threads", "mem_mb", "runtime")
OPTIONAL_KEYS = ("gpu",)


def _read_resource_table(path):
    with open(path) as f:
        table = yaml.safe_load(f)
    for name, row in table.items():
        unknown = set(row) - {*RESOURCE_KEYS, *OPTIONAL_KEYS, "measured"}
        missing = set(RESOURCE_KEYS) - set(row)
        if unknown or missing:
            raise WorkflowError(
                f"{path}, {name}"
                + (f", unknown keys {sorted(unknown)}" if unknown else "")
                + (f", missing {sorted(missing)}" if missing else "")
            )
        for key in (k for k in (*RESOURCE_KEYS, *OPTIONAL_KEYS) if k in row):
            value = row[key]
            if not (isinstance(value, str) or (isinstance(value, int) and value > 0)):
                raise WorkflowError(f"{path}, {name}.{key} is {value!r}, not a positive integer or a function's name")
    return table


RESOURCE_TABLE = _read_resource_table(workflow.source_path("resources.yaml"))


def _resource_value(name, key):
    if name not in RESOURCE_TABLE:
        raise WorkflowError(f"workflow/rules/resources.yaml has no row for {name}")
    value = RESOURCE_TABLE[name][key]
    if not isinstance(value, str):
        return value
    func = globals().get(value)
    if not callable(func):
        raise WorkflowError(f"workflow/rules/resources.yaml, {name}.{key} names no function of the workflow ({value})")
    return func if inspect.signature(func).parameters else func()


def rule_threads(name):
    """The threads of the rule ``name`` (SLURM --cpus-per-task)."""
    return _resource_value(name, "threads")


def rule_resources(name):
    """The mem_mb (SLURM --mem) and runtime in minutes (SLURM --time) of the rule ``name``, and with
    config device: cuda its GPUs (SLURM --gpus) where its row has `gpu` (none when that comes to 0)."""
    out = {key: _resource_value(name, key) for key in ("mem_mb", "runtime")}
    if config["device"] == "cuda" and "gpu" in RESOURCE_TABLE[name]:
        gpus = _resource_value(name, "gpu")
        if callable(gpus) or gpus:
            out["gpu"] = gpus
    return out
