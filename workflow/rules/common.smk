# Shared helpers: config validation, the scene sheet, input paths. No lambdas in rules.
import os
import re
from pathlib import Path

import pandas as pd
from snakemake.utils import validate

validate(config, schema="../schemas/config.schema.yaml")


def config_path(path):
    """A path from the config: relative to the working directory if it exists there, else to the repo."""
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        return p
    beside_repo = Path(workflow.basedir) / p
    return beside_repo if beside_repo.exists() else p


SCENES_SHEET = pd.read_csv(config_path(config["scenes"]), sep="\t", dtype=str, keep_default_na=False)
validate(SCENES_SHEET, schema="../schemas/scenes.schema.yaml")
if SCENES_SHEET["scene"].duplicated().any():
    raise WorkflowError(
        f"{config['scenes']}: duplicate scene ids "
        f"{sorted(SCENES_SHEET.loc[SCENES_SHEET['scene'].duplicated(), 'scene'])}"
    )
SCENES_SHEET = SCENES_SHEET.set_index("scene", drop=False)


def selected_scenes():
    """Scene ids to build: all of the sheet, or those whose id or city is in config['select']."""
    wanted = [str(s) for s in config.get("select", [])]
    if not wanted:
        return list(SCENES_SHEET["scene"])
    known = set(SCENES_SHEET["scene"]) | set(SCENES_SHEET["city"])
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise WorkflowError(
            f"config 'select': unknown scene id(s) or city(ies) {unknown}; "
            f"known scenes {list(SCENES_SHEET['scene'])}, cities {sorted(set(SCENES_SHEET['city']))}"
        )
    mask = SCENES_SHEET["scene"].isin(wanted) | SCENES_SHEET["city"].isin(wanted)
    return list(SCENES_SHEET.loc[mask, "scene"])


def published_scenes():
    return [s for s in selected_scenes() if SCENES_SHEET.loc[s, "source"] == "flatlandia"]


def class_cloud_scenes():
    """Published scenes that ship a class-segmented point cloud (the objects stage starts from it)."""
    if FLAT_FETCH:
        return published_scenes()
    return [s for s in published_scenes() if (FLAT_ROOT / f"maps/{s}/class_segmented_point_cloud.ply").exists()]


def published_cities():
    return {s: SCENES_SHEET.loc[s, "city"] for s in published_scenes()}


def images_scenes():
    return [s for s in selected_scenes() if SCENES_SHEET.loc[s, "source"] == "images"]


def images_dir(wildcards):
    """The image folder of an images scene (from the sheet's path column)."""
    row = SCENES_SHEET.loc[wildcards.scene]
    if row["source"] != "images":
        raise WorkflowError(f"{config['scenes']}: scene {wildcards.scene} is not an images scene")
    if row["path"] and config_path(row["path"]).exists():
        return str(config_path(row["path"]))
    if row.get("url", ""):
        return f"resources/images/{wildcards.scene}"  # fetched by rule fetch_images
    raise WorkflowError(
        f"{config['scenes']}: images folder {row['path']!r} of scene {wildcards.scene} does not exist "
        "and the sheet gives no url to fetch it from"
    )


def images_fetch_params(wildcards):
    row = SCENES_SHEET.loc[wildcards.scene]
    return {"url": row.get("url", ""), "subfolder": row.get("subfolder", "")}


def scene_regex(source):
    """Regex matching the scene ids of the sheet with this source (never matches when none)."""
    ids = [re.escape(s) for s in SCENES_SHEET.loc[SCENES_SHEET["source"] == source, "scene"]]
    return "|".join(ids) if ids else "(?!x)x"


PUBLISHED_SCENE = scene_regex("flatlandia")
IMAGES_SCENE = scene_regex("images")


wildcard_constraints:
    scene="|".join(map(str, SCENES_SHEET["scene"])),
    map_type="gt|depth",
    proposal="gtbb|whole|coarse-sim|coarse-trip|coarse-simtrip",


# ---------------------------------------------------------------- data root
def _resolve_root():
    root = os.environ.get("FLATLANDIA_ROOT") or config["flatlandia_root"]
    return config_path(root).resolve()


FLAT_ROOT_GIVEN = _resolve_root()
FLAT_FETCH = not FLAT_ROOT_GIVEN.exists()
FLAT_ROOT = Path(config["fetch"]["dest"]) if FLAT_FETCH else FLAT_ROOT_GIVEN
FETCH_FLAG = str(Path(config["fetch"]["dest"]).with_suffix(".fetched"))


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


def tokens_files():
    if FLAT_FETCH:
        return [FETCH_FLAG]
    return [p for p in per_scene(str(FLAT_ROOT / "maps/{scene}/tokens.txt")) if Path(p).exists()]


def per_scene(pattern, scenes=None):
    return expand(pattern, scene=scenes if scenes is not None else published_scenes())


def scene_city(wildcards):
    return SCENES_SHEET.loc[wildcards.scene, "city"]


def products_of_the_run():
    """Every artifact `all` asks for, except the manifest that lists them."""
    return (
        per_scene("results/{scene}/maps/reference_map.parquet")
        + per_scene("results/{scene}/maps/reference_map.geojson")
        + per_scene("results/{scene}/maps/reference_map.png")
        + per_scene("results/{scene}/queries/queries.parquet")
        + [
            "results/tables/dataset_stats.parquet",
            "results/tables/dataset_stats.md",
            "results/tables/recovery.parquet",
            "results/tables/availability.parquet",
        ]
        + per_scene("results/{scene}/sfm/classified_points.parquet", images_scenes())
        + per_scene("results/{scene}/sfm/sfm_summary.png", images_scenes())
        + per_scene("results/{scene}/align/alignment.json", images_scenes())
        + per_scene("results/{scene}/objects/objects.ply", images_scenes())
        + per_scene("results/{scene}/maps/reference_map.geojson", images_scenes())
        + per_scene("results/{scene}/maps/reference_map.png", images_scenes())
        + per_scene("results/{scene}/queries/queries.parquet", images_scenes())
        + ["results/tables/fine_localization.parquet", "results/tables/fine_localization.md"]
        + ["results/tables/coarse_localization.parquet", "results/tables/coarse_localization.md"]
        + per_scene("results/{scene}/objects/objects.parquet", class_cloud_scenes())
        + per_scene("results/{scene}/objects/objects.ply", class_cloud_scenes())
        + per_scene("results/{scene}/align/alignment.json", class_cloud_scenes())
        + (["results/tables/reference_map_reproduction.parquet"] if class_cloud_scenes() else [])
    )


def all_targets():
    return products_of_the_run() + report_figures() + ["results/manifest.parquet"]


# ---------------------------------------------------------------- objects inputs
def objects_inputs(wildcards):
    s = wildcards.scene
    return {
        "cloud": flatlandia_file(f"maps/{s}/class_segmented_point_cloud.ply"),
        "transformations": flatlandia_file(f"maps/{s}/transformations.json"),
        "reference_map": flatlandia_file(f"individual_reference_maps/map_{s}.json"),
        # label transfer uses the class labels of the *other* scenes' maps
        "other_maps": [
            flatlandia_file(f"individual_reference_maps/map_{o}.json") for o in published_scenes() if o != s
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


# ---------------------------------------------------------------- coarse (coarse.smk, report.smk)
COARSE_LOSSES = ["sim", "trip", "simtrip"]
COARSE = config.get("coarse", {})
# training / baseline seed: the master seed + coarse.seed_offset
COARSE_SEED = int(config.get("seed", 0)) + int(COARSE.get("seed_offset", 0))
COARSE_TRAIN = {**COARSE.get("train", {}), "seed": COARSE_SEED}


def coarse_losses():
    """The losses of this run (config coarse.losses), each one trained model."""
    return list(COARSE.get("losses", COARSE_LOSSES))


# ---------------------------------------------------------------- fine (fine.smk, report.smk)
FINE_MODELS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
FINE_COARSE = {"coarse-sim": "Sim", "coarse-trip": "Trip", "coarse-simtrip": "Sim+Trip"}


def fine_cfg():
    return config.get("fine", {})


def fine_runs():
    """Run names {method}_{map_type}_{proposal} from config fine.runs (methods x map types x proposals)."""
    runs = fine_cfg().get("runs", {})
    grid = [
        f"{m}_{t}_{p}"
        for m in runs.get("methods", ["geo"])
        for t in runs.get("map_types", ["gt", "depth"])
        for p in runs.get("proposals", ["gtbb"])
    ]
    return grid + [r for r in runs.get("extra", []) if r not in grid]


def fine_eval_inputs(wildcards):
    inp = {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet"),
        "queries": per_scene("results/{scene}/queries/queries.parquet"),
    }
    if wildcards.method != "geo":
        regime = fine_train_regime(wildcards.proposal)
        inp["checkpoint"] = f"results/fine/models/{wildcards.method}_{wildcards.map_type}_{regime}/checkpoint.pt"
    if wildcards.proposal in FINE_COARSE:
        loss = wildcards.proposal.split("-", 1)[1]
        inp["coarse"] = f"results/coarse/{loss}/proposals.parquet"
    return inp


def fine_train_regime(proposal):
    """Training proposals of the learned model a run evaluates: ``coarse`` (simulated coarse
    proposals) for runs on coarse proposals when fine.coarse_training.enabled, else ``gtbb``."""
    on = fine_cfg().get("coarse_training", {}).get("enabled", True)
    return "coarse" if proposal in FINE_COARSE and on else "gtbb"


def fine_eval_params(wildcards):
    p = wildcards.proposal
    strategy = fine_cfg().get("coarse_strategy", "2N_LM")
    label = {"gtbb": "GT-BB", "whole": "whole map"}.get(p, f"{FINE_COARSE.get(p, p)} {strategy}")
    regime = fine_train_regime(p) if wildcards.method != "geo" else ""  # "": the solver, not trained
    crop = float(fine_cfg().get("coarse_training", {}).get("crop_m", 0.0)) if regime == "coarse" else 0.0
    return {
        "method": wildcards.method,
        "proposal": p,
        "strategy": strategy,
        "strategy_label": label,
        "train_regime": regime,
        "crop_m": crop,
    }


def fine_model_name(wildcards):
    return FINE_MODELS[wildcards.model]


def fine_train_params(wildcards):
    """fine.train, updated by fine.train_overrides[{model}] (e.g. fewer epochs for the slower GATs)."""
    return {**fine_cfg().get("train", {}), **fine_cfg().get("train_overrides", {}).get(wildcards.model, {})}


# ---------------------------------------------------------------- report inputs
def fine_trained_models():
    """(model, map_type, training proposals) of every learned fine run of the config (geo needs no training)."""
    out = []
    for run in fine_runs():
        method, map_type, proposal = run.rsplit("_", 2)
        key = (method, map_type, fine_train_regime(proposal))
        if method != "geo" and key not in out:
            out.append(key)
    return out


def heatmap_scene():
    """The scene of the coarse heat map: config report.heatmap_scene, else the first published scene."""
    wanted = str(config.get("report", {}).get("heatmap_scene", ""))
    scenes = published_scenes()
    return wanted if wanted in scenes else (scenes[0] if scenes else None)


def report_figures():
    if not published_scenes():
        return []
    out = [
        "results/figures/training_curves.png",
        "results/figures/fine_error_cdf.png",
        "results/figures/fine_error_vs_objects.png",
    ]
    return out + [f"results/figures/coarse_scores_{heatmap_scene()}.png"]


# ---------------------------------------------------------------- tables inputs
def result_tables():
    """Every result table of the run (Parquet); `snakemake tables` builds just these."""
    return [p for p in products_of_the_run() if p.startswith("results/tables/") and p.endswith(".parquet")]
