"""Fine learned baselines benchmark: training speed and, with ``--full``, accuracy.

Prints, for each ``--models`` x ``--map-types`` under the merged config (config/config.yaml, then
``--configfile`` files, then fine.train_overrides[model]):
1. seconds per training epoch on the train split of every scene (GT-BB proposals), measured over
   ``--epochs`` epochs including the per-epoch validation pass, and the extrapolation to 1000;
2. with ``--full``: the whole run of ``fine.train.epochs`` epochs, then the best-on-validation
   model's test-split median error (m, deg) and share within (10 m, 20 deg), with GT-BB proposals
   and, where results/coarse/simtrip/proposals.parquet exists, with its 2N_LM proposals.

``--simulated-proposals K`` adds K copies of every training (and validation) query with a
simulated coarse proposal (``proposals.simulated_coarse_proposals``); ``--no-gtbb`` trains on
those alone: the experiment behind docs/measurements.md, "Simulated coarse proposals".

Targets: 1000 MLP epochs under 10 minutes on 2 CPU cores; MLP on depth maps with GT-BB
median <= 5 m. Wall and CPU (process) seconds are both given, as the machine may be shared.
Run from the repository root after the pipeline has made results/{scene}/queries and maps:
    python benchmarks/bench_fine_train.py [--models mlp] [--map-types depth] [--threads 1] [--full]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from flatlandia import checkpoints, config, proposals
from flatlandia.fine import models, training

MODEL_NAMES = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
TARGET_1000_S = 10 * 60
TARGET_MEDIAN_M = 5.0


def load_samples(
    results: Path,
    cfg: models.FineTrainConfig,
    simulated: int = 0,
    gtbb: bool = True,
    crop_m: float = 0.0,
    val_coarse_only: bool = False,
) -> dict[str, list]:
    """Train and val samples as rule fine_train builds them (flatlandia.fine.training.training_samples:
    ``simulated`` copies with simulated coarse proposals, GT-BB kept when ``gtbb``), test samples
    with GT-BB proposals and, where results/coarse/simtrip/proposals.parquet exists, its 2N_LM ones."""
    out: dict[str, list] = {"test": [], "test_coarse": []}
    coarse_p = results / "coarse/simtrip/proposals.parquet"
    coarse = pd.read_parquet(coarse_p) if coarse_p.exists() else None
    if coarse is not None:
        coarse = coarse[(coarse["strategy"] == "2N_LM") & (coarse["map_type"] == cfg.map_type)]
    published = [p for p in results.glob("*/queries/queries.parquet") if p.parts[-3].isdigit()]
    scenes = []
    for qp in sorted(published, key=lambda p: int(p.parts[-3])):  # the workflow's scenes, in its order
        ref_p = qp.parent.parent / "maps/reference_map.parquet"
        if not ref_p.exists():
            continue
        ref, q = pd.read_parquet(ref_p), pd.read_parquet(qp)
        scenes.append((ref, q))
        qs = q[q["split"] == "test"]
        out["test"] += models.samples_from_queries(ref, qs, proposals.gtbb_proposals(ref, qs), cfg)[0]
        if coarse is not None:
            props = proposals.crop_to_densest(ref, coarse[coarse["scene"].astype(str) == qp.parts[-3]], crop_m)
            out["test_coarse"] += models.samples_from_queries(ref, qs, props, cfg)[0]
    ct = {"copies": simulated, "keep_gtbb": gtbb, "crop_m": crop_m}
    out["train"], out["val"] = training.training_samples(
        scenes, cfg, "coarse" if simulated else "gtbb", ct, val_keep_gtbb=gtbb and not val_coarse_only
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--configfile", type=Path, nargs="*", default=[])
    ap.add_argument("--models", nargs="+", default=["mlp"], choices=sorted(MODEL_NAMES))
    ap.add_argument("--map-types", nargs="+", default=["depth"], choices=["gt", "depth"])
    ap.add_argument("--epochs", type=int, default=20, help="epochs timed when not --full")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--full", action="store_true", help="train the configured epochs and report test errors")
    ap.add_argument("--simulated-proposals", type=int, default=0, help="copies with simulated coarse proposals")
    ap.add_argument("--no-gtbb", action="store_true", help="train on simulated proposals only")
    ap.add_argument(
        "--save",
        type=Path,
        default=None,
        help="save the trained model here (a checkpoint per run: PATH with -{model}_{map} before the suffix)",
    )
    ap.add_argument(
        "--val-coarse-only",
        action="store_true",
        help="with --simulated-proposals: validate (pick the best epoch) on simulated proposals only",
    )
    ap.add_argument(
        "--crop-m",
        type=float,
        default=0.0,
        help="cut coarse and simulated proposals to their densest objects within this radius",
    )
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    fcfg = config.config_section([Path("config/config.yaml"), *args.configfile], "fine")
    print(f"# Fine training benchmark, {args.threads} thread(s)")
    print(
        "| model | map | train / val / test | epochs | s / epoch | CPU s / epoch | 1000 epochs (min) | best epoch |"
        " test median | within (10 m, 20°) | coarse 2N_LM median |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for slug in args.models:
        for mt in args.map_types:
            train_cfg = {**fcfg.get("train", {}), **fcfg.get("train_overrides", {}).get(slug, {})}
            cfg = models.FineTrainConfig.from_dict({**train_cfg, "model": MODEL_NAMES[slug], "map_type": mt})
            if not args.full:
                cfg.epochs = args.epochs
            s = load_samples(
                args.results, cfg, args.simulated_proposals, not args.no_gtbb, args.crop_m, args.val_coarse_only
            )
            if not s["train"]:
                raise SystemExit(f"{args.results}: no */queries/queries.parquet with maps; run the pipeline first")
            t0, c0 = time.perf_counter(), time.process_time()
            res = training.train(s["train"], s["val"], cfg)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            if args.save:
                checkpoints.save_checkpoint(res, args.save.with_name(f"{args.save.stem}-{slug}_{mt}{args.save.suffix}"))
            per, per_cpu = wall / cfg.epochs, cpu / cfg.epochs
            test = within = coarse = "-"
            if args.full and s["test"]:
                e_m, e_deg = models.errors_metres(models.predict(res["model"], s["test"]), s["test"], cfg)
                test = f"{np.median(e_m):.2f} m, {np.median(e_deg):.1f}°"
                within = f"{100 * np.mean((e_m < 10) & (e_deg < 20)):.1f} %"
            if args.full and s["test_coarse"]:
                e_m, e_deg = models.errors_metres(models.predict(res["model"], s["test_coarse"]), s["test_coarse"], cfg)
                coarse = f"{np.median(e_m):.2f} m, {np.median(e_deg):.1f}°"
            sizes = "/".join(str(len(s[k])) for k in ("train", "val", "test"))
            print(
                f"| {cfg.model} | {mt} | {sizes} | {cfg.epochs} | {per:.3f} | {per_cpu:.3f} | {per * 1000 / 60:.1f} |"
                f" {res['best_epoch']} | {test} | {within} | {coarse} |",
                flush=True,
            )
    print(
        f"\ntargets: 1000 MLP epochs under {TARGET_1000_S / 60:.0f} min; MLP depth GT-BB median <= {TARGET_MEDIAN_M} m"
    )


if __name__ == "__main__":
    main()
