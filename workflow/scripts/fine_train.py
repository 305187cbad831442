"""Rule fine_train: one learned fine-localization model (MLP | MLP+ATT | GAT | GAT+ATT) on one map
type and one training regime (flatlandia.fine.training.train_model).

Trains on the train split of every scene with GT-BB proposals (``gtbb``, the paper's training) or
with simulated coarse proposals (``coarse``, config fine.coarse_training; for the runs evaluated on
coarse proposals; by default it starts from the ``gtbb`` model and trains fine.coarse_training.epochs
more, sharing that training), keeps the best-on-validation weights and saves them with the resolved config
(torch.save({'state_dict', 'config', ...})).
"""

import pandas as pd
import torch

from flatlandia import checkpoints, proposals
from flatlandia import device as device_module
from flatlandia.fine import models, training
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    device = device_module.resolve(smk.config["device"])  # a cuda without a GPU stops here, one line
    log.info("device: %s", device_module.describe(device))
    p, regime = smk.params, smk.wildcards.train
    coarse_training = dict(p["fine.coarse_training"])
    train = proposals.training_settings(p["fine.train"], p["fine.train_overrides.{model}"], coarse_training, regime)
    cfg = models.FineTrainConfig.from_dict({**train, "model": p.model, "map_type": smk.wildcards.map_type})
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    res, history, meta = training.train_model(
        scenes,
        cfg,
        regime,
        coarse_training,
        init=smk.input.get("init") or None,
        log=log,
        progress=rule_log.progress(log, f"{cfg.model} {cfg.map_type}"),
        source=smk.input.queries[0] if smk.input.queries else "benchmark_scenes",
        device=device,
    )
    checkpoints.save_checkpoint(res, smk.output.checkpoint)
    files.write_parquet(history, smk.output.history, meta)
    log.info(
        "best epoch %d, validation median %.2f m, %.1f s, %d parameters",
        res["best_epoch"],
        res["best_val_median_m"],
        res["seconds"],
        meta["n_parameters"],
    )


rule_log.run(main, snakemake)  # noqa: F821
