"""Rule coarse_train: one coarse-localization GAT per loss (Sim | Trip | Sim+Trip) on every scene's train split.

Best-on-validation weights are saved with their resolved config (torch.save({'state_dict',
'config', 'history', ...})); the training curve goes to a Parquet table.
"""

import pandas as pd
import torch

from flatlandia import checkpoints, io, runlog
from flatlandia.coarse import retrieval, training
from flatlandia.errors import InputError


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    cfg = retrieval.CoarseConfig.from_dict({**dict(smk.params.train), "loss": smk.wildcards.loss})
    scenes = []
    for ref_path, q_path, s_path in zip(smk.input.reference_maps, smk.input.queries, smk.input.similarity):
        q = pd.read_parquet(q_path)
        scenes.append((pd.read_parquet(ref_path), q, pd.read_parquet(s_path)))
    ds = retrieval.build_dataset(scenes, cfg, splits=("train", "val"))
    log.info(
        "%s: %d train / %d val queries over %d scenes; config %s",
        retrieval.LOSSES[cfg.loss],
        len(ds.split("train")),
        len(ds.split("val")),
        len(scenes),
        cfg.to_dict(),
    )
    if not ds.split("train") or not ds.split("val"):
        raise InputError(
            smk.input.queries[0] if smk.input.queries else "benchmark_scenes",
            f"{len(ds.split('train'))} training and {len(ds.split('val'))} validation queries for the coarse "
            f"{cfg.loss} model: the benchmark scenes (config benchmark_scenes) hold too few queries to train on",
        )
    res = training.train(ds, cfg, log=log, progress=runlog.progress(log, f"coarse {cfg.loss}"))
    checkpoints.save_checkpoint(res, smk.output.model)
    meta = {
        "config": res["config"],
        "best_epoch": res["best_epoch"],
        "best_val": res["best_val"],
        "seconds": res["seconds"],
        "seconds_per_epoch": res["seconds_per_epoch"],
        "n_parameters": checkpoints.n_parameters(res["model"]),
    }
    io.write_parquet(pd.DataFrame(res["history"]), smk.output.history, meta)
    log.info(
        "best epoch %d (validation %.4f); %.1f s, %.2f s per training epoch; %d parameters",
        res["best_epoch"],
        res["best_val"],
        res["seconds"],
        res["seconds_per_epoch"],
        meta["n_parameters"],
    )


runlog.run(main, snakemake)  # noqa: F821
