"""Coarse map localization benchmark: similarity precompute, training speed, query scoring, Table 3.

Prints
1. the similarity target S: seconds per scene (and per query) of ``target.scene_similarity``;
2. training: seconds per epoch of one Sim+Trip model under the paper's settings (config/paper.yaml
   over config/config.yaml: 800 epochs, batch 20), measured over ``--epochs`` epochs, plus the cost
   of one validation pass, extrapolated to the full run (``--full`` trains all of it and measures);
3. scoring one query: median seconds with the scene's reference embeddings cached and without,
   over ``--queries`` test queries, for the trained results/coarse/simtrip/model.pt;
4. the Table 3 figures of results/tables/coarse_localization.parquet beside the paper's.

One CPU thread throughout; wall and CPU (process) seconds are both given, as the machine is shared.
Run from the repository root after the pipeline:  python benchmarks/bench_coarse.py [--scenes 0 12]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from flatlandia import checkpoints, config
from flatlandia.coarse import evaluation, retrieval, target, training

TARGET_800_S = 15 * 60
TARGET_QUERY_S = 0.005


def load_scenes(results: Path, scenes: list[str], with_similarity: bool = True) -> list:
    out = []
    for s in scenes:
        ref = pd.read_parquet(results / s / "maps/reference_map.parquet")
        q = pd.read_parquet(results / s / "queries/queries.parquet")
        sim = pd.read_parquet(results / s / "coarse/target.parquet") if with_similarity else None
        out.append((ref, q, sim))
    return out


def bench_similarity(scenes: list[str], results: Path, cfg: dict) -> None:
    print("\n## Similarity target S (GT local maps, all queries of a scene)")
    scfg = target.SimilarityConfig(**cfg.get("similarity", {}))
    print(f"config {scfg.to_dict()}")
    print("| scene | objects | queries | seconds | CPU s | ms / query |\n|---|---|---|---|---|---|")
    tot_w = tot_c = tot_q = 0.0
    for s in scenes:
        ref = pd.read_parquet(results / s / "maps/reference_map.parquet")
        q = pd.read_parquet(results / s / "queries/queries.parquet")
        w0, c0 = time.perf_counter(), time.process_time()
        target.scene_similarity(ref, q, scfg)
        w, c = time.perf_counter() - w0, time.process_time() - c0
        tot_w, tot_c, tot_q = tot_w + w, tot_c + c, tot_q + len(q)
        print(f"| {s} | {len(ref)} | {len(q)} | {w:.2f} | {c:.2f} | {1000 * w / max(len(q), 1):.1f} |")
    print(f"| all | | {int(tot_q)} | {tot_w:.2f} | {tot_c:.2f} | {1000 * tot_w / max(tot_q, 1):.1f} |")


def bench_training(
    scenes: list[str], results: Path, cfg: dict, epochs: int, full: bool, loss: str, save: Path | None = None
) -> None:
    train = {**cfg.get("train", {}), "loss": loss}
    paper_epochs = int(train.get("epochs", 800))
    data = load_scenes(results, scenes)
    ccfg = retrieval.CoarseTrainConfig.from_dict({**train, "epochs": paper_epochs if full else epochs})
    ds = training.training_dataset(data, ccfg)  # rule coarse_train's entry functions
    print(
        f"\n## Training ({retrieval.LOSSES[loss]}, {len(ds.split('train'))} train / {len(ds.split('val'))} val "
        f"queries, batch {ccfg.batch_size}, validation every {ccfg.eval_every} epochs)"
    )
    w0, c0 = time.perf_counter(), time.process_time()
    res, hist, _ = training.train_model(ds, ccfg)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    per_epoch = float(hist["epoch_seconds"].median())
    model = res["model"]
    v0 = time.perf_counter()
    training.validation_metric(model, ds, ds.split("val"), ccfg)
    val_s = time.perf_counter() - v0
    n_val = len(range(0, paper_epochs, ccfg.eval_every)) + (0 if (paper_epochs - 1) % ccfg.eval_every == 0 else 1)
    extrap = paper_epochs * per_epoch + n_val * val_s
    print(
        f"{ccfg.epochs} epochs trained in {wall:.1f} s wall / {cpu:.1f} s CPU; median {per_epoch:.3f} s per "
        f"training epoch; one validation pass {val_s:.3f} s"
    )
    if full:
        print(
            f"{paper_epochs} epochs measured: {wall:.1f} s = {wall / 60:.1f} min "
            f"(target < {TARGET_800_S / 60:.0f} min: {'met' if wall < TARGET_800_S else 'MISSED'})"
        )
    print(
        f"{paper_epochs} epochs extrapolated: {paper_epochs} x {per_epoch:.3f} s + {n_val} validations x "
        f"{val_s:.3f} s = {extrap:.0f} s = {extrap / 60:.1f} min (target < {TARGET_800_S / 60:.0f} min: "
        f"{'met' if extrap < TARGET_800_S else 'MISSED'})"
    )
    print(
        f"loss first / last epoch: {hist['train_loss'].iloc[0]:.4f} / {hist['train_loss'].iloc[-1]:.4f}; "
        f"best validation {res['best_val']:.4f} at epoch {res['best_epoch']}"
    )
    if save is not None:
        checkpoints.save_checkpoint(res, save)
        print(f"checkpoint: {save}")


def bench_query(scenes: list[str], results: Path, n_queries: int) -> None:
    path = results / "coarse/simtrip/model.pt"
    print(f"\n## Scoring one query ({path})")
    if not path.exists():
        print("no trained model: run the pipeline first")
        return
    model, ccfg = checkpoints.load_checkpoint(path, retrieval.CoarseTrainConfig, retrieval.build_model)
    ds = retrieval.build_dataset(load_scenes(results, scenes, with_similarity=False), ccfg, splits=("test",))
    rng = np.random.default_rng(0)
    samples = [ds.samples[i] for i in rng.permutation(len(ds.samples))[:n_queries]]
    rows = []
    for mt in retrieval.MAP_TYPES:
        for s in samples:
            rows.append(
                {"map_type": mt, "objects": len(ds.refs[s.scene]), **evaluation.time_one_query(model, ds, s, mt, 20)}
            )
    t = pd.DataFrame(rows)
    for col, label in (
        ("score_cached_ref_s", "reference embeddings cached"),
        ("score_with_ref_s", "reference graph embedded too"),
    ):
        ms = 1000 * t[col]
        print(
            f"{label}: median {ms.median():.2f} ms, 95th percentile {ms.quantile(0.95):.2f} ms, max {ms.max():.2f} ms "
            f"over {len(t)} (query, map type) pairs (scene sizes {t['objects'].min()}-{t['objects'].max()} objects; "
            f"target < {1000 * TARGET_QUERY_S:.0f} ms: {'met' if ms.median() < 1000 * TARGET_QUERY_S else 'MISSED'})"
        )


def print_table(results: Path) -> None:
    path = results / "tables/coarse_localization.parquet"
    print(f"\n## Table 3 ({path})")
    if not path.exists():
        print("no table: run the pipeline first")
        return
    t = pd.read_parquet(path)
    print("| loss | NS | map | ours P / R / S | paper P / R / S | queries |\n|---|---|---|---|---|---|")
    for r in t.itertuples():
        paper = (
            "-"
            if not np.isfinite(r.paper_success)
            else f"{r.paper_precision:.3f} / {r.paper_recall:.3f} / {r.paper_success:.3f}"
        )
        print(
            f"| {r.loss} | {r.strategy} | {r.map_type} | {r.precision:.3f} / {r.recall:.3f} / {r.success:.3f} | "
            f"{paper} | {r.queries} |"
        )
    key = t[(t["loss"] == "Sim+Trip") & (t["strategy"] == "R_30")].set_index("map_type")["success"]
    for mt, goal in (("gt", 0.60), ("depth", 0.60)):
        if mt in key:
            print(
                f"Sim+Trip R_30 success, {mt} maps: {key[mt]:.3f} (target >= {goal:.2f}: "
                f"{'met' if key[mt] >= goal else 'MISSED'})"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results", type=Path)
    ap.add_argument(
        "--scenes", nargs="*", default=None, help="scene ids (default: every scene with a similarity table)"
    )
    ap.add_argument(
        "--config",
        nargs="*",
        default=["config/config.yaml", "config/paper.yaml"],
        type=Path,
        help="config files merged in order (their coarse: sections)",
    )
    ap.add_argument("--epochs", type=int, default=5, help="epochs timed for the extrapolation")
    ap.add_argument(
        "--full", action="store_true", help="train the configured epochs (800 with paper.yaml) and time them"
    )
    ap.add_argument("--loss", default="simtrip", choices=list(retrieval.LOSSES))
    ap.add_argument("--save", type=Path, default=None, help="save the trained checkpoint here (not under results/)")
    ap.add_argument("--queries", type=int, default=50, help="test queries timed")
    ap.add_argument("--skip", nargs="*", default=[], choices=["similarity", "training", "query", "table"])
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the rules use 1 per job)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    scenes = args.scenes or sorted(
        (p.parent.parent.name for p in args.results.glob("*/coarse/target.parquet")), key=lambda s: (len(s), s)
    )
    cfg = config.config_section(args.config, "coarse")
    print(
        f"# Coarse localization benchmark: {len(scenes)} scenes, config {[str(p) for p in args.config]}, "
        f"{args.threads} thread(s)"
    )
    if "similarity" not in args.skip:
        bench_similarity(scenes, args.results, cfg)
    if "training" not in args.skip:
        bench_training(scenes, args.results, cfg, args.epochs, args.full, args.loss, args.save)
    if "query" not in args.skip:
        bench_query(scenes, args.results, args.queries)
    if "table" not in args.skip:
        print_table(args.results)


if __name__ == "__main__":
    main()
