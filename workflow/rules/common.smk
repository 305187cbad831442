# Shared helpers: config validation, the scene sheet, the data root, the targets of `all`.
# Input functions of one stage sit in rules/inputs/{stage}.smk, included by its rule file. No lambdas in rules.
import difflib
import hashlib
import os
import sys
from pathlib import Path

import pandas as pd
from snakemake.utils import validate

from flatlandia import config as config_schema
from flatlandia import device as device_check
from flatlandia import paths, vocabulary
from flatlandia.plumbing import module_handlers, stale_locks, scheduler
from flatlandia.plumbing import validate as config_door
from flatlandia.plumbing.errors import InputError
from flatlandia.data.fetch import FetchError, check_dest, download_note

# A lock of this folder left by a killed run is removed before this run locks, when provably stale
# (flatlandia.plumbing.stale_locks); otherwise Snakemake refuses after one line saying whose lock it is.
stale_locks.install(workflow)
# Snakemake's scheduler wakes once a second, not once a second per finished job (flatlandia.plumbing.scheduler).
scheduler.install(workflow)


# Every rule's threads, memory and runtime, from one table: rules/resources.yaml.
include: "resources.smk"


# Every config file of the run (config/config.yaml, --configfile) read again by the workflow's own
# door first (flatlandia.plumbing.validate.read_config): Snakemake's reader keeps the last of a key
# given twice and shares aliased subtrees (an alias bomb); either stops the run with one line.
try:
    for _configfile in workflow.configfiles:
        if os.path.lexists(_configfile):
            config_door.read_config(_configfile)
except InputError as err:
    sys.exit(f"ERROR: {err}")
# Every key checked against workflow/schemas/config.schema.yaml (the one source of defaults)
# before any job: a typo or a wrong type stops the run with one line naming the key.
try:
    RESOLVED_CONFIG = config_schema.resolve(config)
except config_schema.ConfigError as err:
    sys.exit(f"ERROR: config: {err}")
config.clear()
config.update(RESOLVED_CONFIG)


def config_keys(*keys, exclude=(), reads=None):
    """The config keys a rule reads, as its params, named by their dotted keys (PyPSA-Eur's
    config_provider): `params: **config_keys("solver", "city.split")` gives the params "solver" and
    "city.split", which the script reads as `snakemake.params["city.split"]` and `flatlandia audit`
    lists as the rule's settings. A key names a value or a whole section (read whole by a settings
    class); a part in braces is a wildcard of the job ("fine.train_overrides.{model}": its model's
    entry); `exclude` leaves keys of a section out (its value without them); `reads(wildcards)`, when
    given, is the set of the keys one job reads: the others are {} for that job (not read, and left
    out of its provenance record), so a setting reruns only the jobs that read it."""
    out = {}
    for key in keys:
        known = key.split(".{", 1)[0]  # the part without wildcards must exist now
        try:
            value = vocabulary.config_value(config, known)
        except (KeyError, TypeError):
            raise WorkflowError(f"config_keys: the config has no key {known!r}") from None
        if known != key:
            value = _key_of_job(key)
        drop = [e.rsplit(".", 1)[1] for e in exclude if e.rsplit(".", 1)[0] == key]
        out[key] = {k: v for k, v in value.items() if k not in drop} if drop else value
    if reads is None:
        return out
    return {key: _read_by(reads, key, value) for key, value in out.items()}


def _key_of_job(key):
    def param(wildcards):
        return vocabulary.config_value(config, key.format(**wildcards))

    return param


def _read_by(reads, key, value):
    def param(wildcards):
        if key not in reads(wildcards):
            return {}
        return value(wildcards) if callable(value) else value

    return param


def jobs_run_here():
    """Whether this Snakemake runs jobs on this machine: a local run, or a cluster job's own
    Snakemake on its node; not the host that submits a cluster run's jobs (a remote executor's
    --jobs), which needs no GPU of its own."""
    return workflow.remote_exec or workflow.resource_settings.nodes is None


#: whether this workflow is a module of another project's Snakefile (flatlandia.plumbing.module_handlers)
AS_MODULE = module_handlers.as_module(workflow)


def dry_run():
    """Whether this Snakemake only plans (-n), as its output settings say (a run when they do not)."""
    return bool(getattr(getattr(workflow, "output_settings", None), "dryrun", False))


# config 'device': cuda where the jobs run and torch sees no GPU stops here, before any job (torch is
# imported only for cuda); a cluster job checks again on its node, where its Snakemake parses this.
# A dry run warns and plans: a plan for a GPU machine can be previewed anywhere.
DEVICE_PROBLEM = device_check.workflow_check(config["device"], jobs_run_here())
if DEVICE_PROBLEM and dry_run():
    print(f"WARNING: {device_check.dry_run_warning(DEVICE_PROBLEM)}", file=sys.stderr)
elif DEVICE_PROBLEM:
    sys.exit(f"ERROR: {DEVICE_PROBLEM}")


def config_path(path):
    """A path from the config: relative to the working directory if it exists there, else to the
    repository when the workflow runs from its clone; as a module of another project (from a folder
    or a remote source), relative to that project's working directory only, where its config was
    written."""
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists() or REPO_DIR is None or AS_MODULE:
        return p
    beside_repo = Path(REPO_DIR) / p
    return beside_repo if beside_repo.exists() else p


def separated_by_spaces(sheet):
    """The first line of the sheet written with spaces between its columns (an editor that turns
    tabs into spaces), as 'line N: ...'; None when there is none."""
    if len(sheet.columns) == 1 and len(str(sheet.columns[0]).split()) > 1:
        return f"line 1: {str(sheet.columns[0])[:80]!r} is one column"
    if "scene" in sheet.columns:
        for i, cell in enumerate(sheet["scene"]):
            if len(str(cell).split()) > 1:
                return f"line {i + 2}: {str(cell)[:80]!r} is one column"
    return None


def read_scene_sheet(path):
    """The scene sheet, checked against its schema: a problem stops the run with one ERROR line."""
    try:
        sheet = pd.read_csv(path, sep="\t", dtype=str, keep_default_na=False)
    except (OSError, ValueError) as err:
        sys.exit(f"ERROR: {path}: unreadable scene sheet ({err})")
    spaced = separated_by_spaces(sheet)
    if spaced:
        sys.exit(f"ERROR: {path}: {spaced}: the sheet's columns are separated by tabs, not spaces")
    try:
        validate(sheet, schema="../schemas/scenes.schema.yaml")
    except WorkflowError as err:
        sys.exit(f"ERROR: {path}: {' '.join(str(err).split())}")
    dup = sorted(set(sheet.loc[sheet["scene"].duplicated(), "scene"]))
    if dup:
        sys.exit(f"ERROR: {path}: duplicate scene ids {dup}")
    from flatlandia.images import gps_alignment

    align = gps_alignment.sheet_align_problem(sheet)  # the optional column align: gps, none or empty
    if align:
        sys.exit(f"ERROR: {path}: {align}")
    return sheet.set_index("scene", drop=False)


SCENES_SHEET = read_scene_sheet(config_path(config["scenes"]))


def check_scene_names(key):
    """Stop before any job when config[key] names a scene id or city the sheet lacks (with the
    closest known names)."""
    known = list(SCENES_SHEET["scene"]) + sorted(set(SCENES_SHEET["city"]))
    unknown = [str(w) for w in config[key] if str(w) not in known]
    if unknown:
        near = {w: difflib.get_close_matches(w, known, n=1, cutoff=0.6) for w in unknown}
        hint = "; ".join(f"did you mean '{n[0]}' for '{w}'?" for w, n in near.items() if n)
        sys.exit(
            f"ERROR: config: '{key}': unknown scene id(s) or city(ies) {unknown}"
            + (f" ({hint})" if hint else "")
            + f"; known scenes {list(SCENES_SHEET['scene'])}, cities {sorted(set(SCENES_SHEET['city']))}"
        )


check_scene_names("select")
check_scene_names("benchmark_scenes")


def scenes_named(key):
    """Scene ids of the sheet whose id or city is listed in config[key]; all of the sheet if empty
    (names checked by check_scene_names before any rule)."""
    wanted = [str(s) for s in config[key]]
    if not wanted:
        return list(SCENES_SHEET["scene"])
    mask = SCENES_SHEET["scene"].isin(wanted) | SCENES_SHEET["city"].isin(wanted)
    return list(SCENES_SHEET.loc[mask, "scene"])


def selected_scenes():
    """Scene ids whose maps to build: config 'select' (all of the sheet when empty)."""
    return scenes_named("select")


def published_scenes():
    """The selected published scenes (per-scene work of `maps`)."""
    return [s for s in selected_scenes() if SCENES_SHEET.loc[s, "source"] == "flatlandia"]


def benchmark_scenes():
    """The published scenes the models and tables are built on: config 'benchmark_scenes', never
    'select', so selecting a city neither retrains on it alone nor overwrites the benchmark."""
    return [s for s in scenes_named("benchmark_scenes") if SCENES_SHEET.loc[s, "source"] == "flatlandia"]


def check_benchmark_folder(record=paths.BENCHMARK_RECORD):
    """Stop before any job when benchmark_scenes differs from the set the results here were built
    on: the models, tables and label transfer would be overwritten. A benchmark on other scenes
    (e.g. a subset) is a named run in a folder of its own."""
    if not Path(record).exists():
        return
    built = sorted(map(str, pd.read_parquet(record, columns=["scene"])["scene"]))
    wanted = sorted(benchmark_scenes())
    if built != wanted:
        sys.exit(
            f"ERROR: config: benchmark_scenes {wanted} differs from the scenes {built} that the benchmark in "
            f"{paths.RESULTS}/ was built on ({record}): models and tables of another scene set go in a folder of their "
            "own, named by you: snakemake -d runs/<name> ... (or remove results/tables to rebuild here)"
        )


def class_cloud_scenes(scenes=None):
    """Published scenes (the selected ones by default) that ship a class-segmented point cloud
    (the objects stage starts from it)."""
    scenes = published_scenes() if scenes is None else scenes
    if FLAT_FETCH:
        return scenes
    return [s for s in scenes if (FLAT_ROOT / f"maps/{s}/class_segmented_point_cloud.ply").exists()]


def benchmark_cities():
    return {s: SCENES_SHEET.loc[s, "city"] for s in benchmark_scenes()}


def images_scenes():
    return [s for s in selected_scenes() if SCENES_SHEET.loc[s, "source"] == "images"]


def images_folder_problem(scene):
    """What is wrong with an images scene's folder (the sheet's path), or None: a file where the
    folder should be, or no folder and no url that fetches one. One check, for the run's start
    (check_images_folders) and for a job asked for by name (images_dir)."""
    row = SCENES_SHEET.loc[scene]
    path = config_path(row["path"]) if row.get("path", "") else None
    if path is not None and path.exists() and not path.is_dir():
        return f"its path {str(path)!r} is a file, not a folder"
    if (path is None or not path.exists()) and not row.get("url", ""):
        given = f"its path {str(path)!r} does not exist" if path is not None else "its path is empty"
        return (
            f"{given} and the row gives no url to fetch the photos from (give the folder of photos in "
            "the path column; the sheet is tab-separated)"
        )
    return None


def check_images_folders():
    """Stop before any job when a selected images scene's folder is wrong
    (images_folder_problem): otherwise the first rule's input function fails inside Snakemake,
    with a traceback."""
    for scene in images_scenes():
        problem = images_folder_problem(scene)
        if problem:
            sys.exit(f"ERROR: {config['scenes']}: images scene {scene}: {problem}")


check_images_folders()


def align_mode(scene):
    """images.align.mode of an images scene: its align cell in the scene sheet, else the config's."""
    from flatlandia.images import gps_alignment

    return gps_alignment.scene_mode(SCENES_SHEET.loc[scene].get("align", ""), config["images"]["align"]["mode"])


def localization_scenes():
    """Images scenes whose queries the benchmark's methods localize (scene_localization), those
    on a GPS-aligned map (a local frame has no metres to measure errors in)."""
    return [s for s in images_scenes() if align_mode(s) == "gps"]


def scene_source(wildcards):
    """Where a scene comes from (config/scenes.tsv): ``flatlandia`` (published data) or ``images``."""
    return SCENES_SHEET.loc[wildcards.scene, "source"]


wildcard_constraints:
    scene="|".join(map(str, SCENES_SHEET["scene"])),
    map_type="|".join(vocabulary.MAP_TYPES),
    proposal="|".join(vocabulary.PROPOSALS),


# ---------------------------------------------------------------- data root
def _written_root():
    """The data folder as the user wrote it: flatlandia_root when given explicitly (--configfile,
    --config, a module's config), else the environment variable FLATLANDIA_ROOT, else the default
    config's."""
    env = os.environ.get("FLATLANDIA_ROOT")
    return env if env and "flatlandia_root" not in CONFIG_GIVEN else config["flatlandia_root"]


def as_written(resolved, written):
    """The data folder as the jobs name it: relative to the working folder when the user wrote a
    relative path, so that a run folder copied into another clone with the data beside it names
    the same files (its jobs' inputs and settings are unchanged: nothing reruns); absolute when
    written absolute."""
    if Path(str(written)).expanduser().is_absolute():
        return resolved
    return Path(os.path.relpath(resolved, Path.cwd()))


FLAT_ROOT_GIVEN = config_path(_written_root()).resolve()
FLAT_FETCH = not FLAT_ROOT_GIVEN.exists()
# a fetch writes fetch.dest, before any job: only a folder below resources/ or the declared data folder
# (flatlandia_root, absent), never '.', '..', the working folder, its parents, the root or home, a
# dot-folder, a Python installation or environment (.venv), the source tree (flatlandia.data.fetch.check_dest)
if FLAT_FETCH:
    try:
        check_dest(config["fetch"]["dest"], data_folder=FLAT_ROOT_GIVEN)
    except FetchError as err:
        sys.exit(f"ERROR: config: {err}")
FLAT_ROOT = Path(config["fetch"]["dest"]) if FLAT_FETCH else as_written(FLAT_ROOT_GIVEN, _written_root())
FETCH_FLAG = str(Path(config["fetch"]["dest"]).with_suffix(".fetched"))
_SAID_DOWNLOADS = set()


def say_download(key, what, rule, url, dest, why):
    """One line on the terminal, once, when the plan downloads (flatlandia.data.fetch.download_note):
    called by the fetch rules' input functions, which Snakemake calls for the jobs it plans, in a dry
    run too; not in a cluster job's own Snakemake (the submitting host said it)."""
    if key in _SAID_DOWNLOADS or not workflow.is_main_process:
        return
    _SAID_DOWNLOADS.add(key)
    line = download_note(what, rule, url, dest, why, config["fetch"]["max_download_mb"])
    print(f"flatlandia: {line}", file=sys.stderr)


def missing_data_folder():
    """Why the published data is downloaded: the data folder as written, and where it was looked for."""
    setting = "FLATLANDIA_ROOT" if _written_root() != config["flatlandia_root"] else "flatlandia_root"
    return (
        f"{setting} {str(_written_root())!r} does not exist here ({FLAT_ROOT_GIVEN}): set it to a copy of the data "
        "to skip the download"
    )


def flatlandia_file(relpath):
    """Path of a published data file; while the data must be fetched, the fetch flag instead."""
    return FETCH_FLAG if FLAT_FETCH else str(FLAT_ROOT / relpath)


def scene_data_inputs(wildcards):
    """The published files a scene is built from (tracked so edits trigger a rebuild)."""
    s = wildcards.scene
    return {
        "reference_map": flatlandia_file(f"individual_reference_maps/map_{s}.json"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
        "local_maps": flatlandia_file("local_maps.json"),
    }


def per_scene(pattern, scenes=None):
    return expand(pattern, scene=scenes if scenes is not None else published_scenes())


def scene_city(wildcards):
    return SCENES_SHEET.loc[wildcards.scene, "city"]


def map_products():
    """Per-scene maps of the selected scenes (the `maps` target): reference maps, queries with their
    local maps, objects; for images scenes the audit-to-map chain. No training, no shared tables."""
    published, images, clouds = published_scenes(), images_scenes(), class_cloud_scenes()
    return (
        [paths.reference_map(s, ext) for ext in ("parquet", "geojson", "png") for s in published]
        + [paths.queries(s) for s in published]
        + [paths.classified_points(s) for s in images]
        + [paths.sfm(s, "sfm_summary.png") for s in images]
        + [paths.gps_alignment(s) for s in images]
        + [paths.objects(s, "ply") for s in images]
        + [paths.reference_map(s, ext) for ext in ("geojson", "png") for s in images]
        + [paths.queries(s) for s in images]
        + [paths.objects(s, ext) for ext in ("parquet", "ply") for s in clouds]
        + [paths.principal_plane(s) for s in clouds]
    )


#: the result tables of `benchmark` (the others are parts of a rule's outputs beside these)
BENCHMARK_TABLES = [
    paths.table("dataset_stats"),
    paths.table("dataset_stats", "md"),
    paths.table("recovery"),
    paths.table("availability"),
    paths.table("fine_localization"),
    paths.table("fine_localization", "md"),
    paths.table("coarse_localization"),
    paths.table("coarse_localization", "md"),
]


def benchmark_products():
    """The dataset tables, the models and the localization tables (the `benchmark` target), and the
    selected images scenes localized by the benchmark's methods."""
    return (
        BENCHMARK_TABLES
        + [paths.solver_priors_gt(vocabulary.WHOLE)]
        + beyond_products()
        + ([paths.table("reference_map_reproduction")] if class_cloud_scenes(benchmark_scenes()) else [])
        + [paths.scene_localization(s) for s in localization_scenes()]
    )


def products_of_the_run():
    """Every artifact `all` asks for, except the manifest that lists them."""
    return map_products() + benchmark_products()


def all_targets():
    return products_of_the_run() + report_figures() + scene_viewers() + [paths.manifest()]


# before any job: never overwrite a benchmark built on other scenes
check_benchmark_folder()
