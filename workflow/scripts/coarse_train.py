"""Rule coarse_train: one coarse-localization GAT per loss (Sim | Trip | Sim+Trip) on every scene's train split
(flatlandia.coarse.training: ``training_dataset``, ``train_model``).

Best-on-validation weights are saved with their resolved config (torch.save({'state_dict',
'config', 'history', ...})); the training curve goes to a Parquet table.
"""

import pandas as pd
import torch

from flatlandia import checkpoints
from flatlandia import device as device_module
from flatlandia.coarse import retrieval, training
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    device = device_module.resolve(smk.config["device"])  # a cuda without a GPU stops here, one line
    log.info("device: %s", device_module.describe(device))
    p = smk.params  # training seed: the master seed + coarse.seed_offset
    seed = int(p["seed"]) + int(p["coarse.seed_offset"])
    cfg = retrieval.CoarseTrainConfig.from_dict({**dict(p["coarse.train"]), "seed": seed, "loss": smk.wildcards.loss})
    scenes = [
        (pd.read_parquet(r), pd.read_parquet(q), pd.read_parquet(s))
        for r, q, s in zip(smk.input.reference_maps, smk.input.queries, smk.input.similarity)
    ]
    source = smk.input.queries[0] if smk.input.queries else "benchmark_scenes"
    ds = training.training_dataset(scenes, cfg, log=log, source=source)
    progress = rule_log.progress(log, f"coarse {cfg.loss}")
    res, history, meta = training.train_model(ds, cfg, log=log, progress=progress, device=device)
    checkpoints.save_checkpoint(res, smk.output.model)
    files.write_parquet(history, smk.output.history, meta)
    log.info(
        "best epoch %d (validation %.4f); %.1f s, %.2f s per training epoch; %d parameters",
        res["best_epoch"],
        res["best_val"],
        res["seconds"],
        res["seconds_per_epoch"],
        meta["n_parameters"],
    )


rule_log.run(main, snakemake)  # noqa: F821
