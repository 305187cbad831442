"""Rule fine_train: one learned fine-localization model (MLP | MLP+ATT | GAT | GAT+ATT) on one map
type and one training regime.

Trains on the train split of every scene with GT-BB proposals (``gtbb``, the paper's training) or
with simulated coarse proposals (``coarse``, config fine.coarse_training; for the runs evaluated on
coarse proposals; by default it starts from the ``gtbb`` model and trains fine.coarse_training.epochs
more, sharing that training), keeps the best-on-validation weights and saves them with the resolved config
(torch.save({'state_dict', 'config', ...})).
"""

import numpy as np
import pandas as pd
import torch

from flatlandia import checkpoints, io, proposals, runlog
from flatlandia.errors import InputError
from flatlandia.fine import learned, training


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    cfg = learned.FineConfig.from_dict(
        {**dict(smk.params.train), "model": smk.params.model, "map_type": smk.wildcards.map_type}
    )
    regime, ct = smk.wildcards.train, dict(smk.params.coarse_training)
    rng = np.random.default_rng(cfg.seed)
    train, val = [], []
    for ref_path, q_path in zip(smk.input.reference_maps, smk.input.queries):
        ref, q = pd.read_parquet(ref_path), pd.read_parquet(q_path)
        for split, dest, copies in (("train", train, int(ct["copies"])), ("val", val, 1)):
            qs = q[q["split"] == split]
            for props in proposals.training_proposals(
                ref, qs, regime, rng, copies, bool(ct["keep_gtbb"]), float(ct["crop_m"])
            ):
                dest += learned.samples_from_queries(ref, qs, props, cfg)[0]
    log.info(
        "%s on %s maps, %s proposals: %d train / %d val samples, config %s, coarse training %s",
        cfg.model,
        cfg.map_type,
        regime,
        len(train),
        len(val),
        cfg.to_dict(),
        ct if regime == "coarse" else "-",
    )
    if not train or not val:
        raise InputError(
            smk.input.queries[0] if smk.input.queries else "benchmark_scenes",
            f"{len(train)} training and {len(val)} validation samples for {cfg.model} on {cfg.map_type} maps: "
            "the benchmark scenes (config benchmark_scenes) hold too few queries to train on",
        )
    init = None
    if smk.input.get("init"):  # warm start: the GT-BB-trained model of the same model and map type
        start, _ = checkpoints.load_checkpoint(smk.input.init, learned.FineConfig, learned.build_model)
        init = start.state_dict()
        log.info("starting from %s", smk.input.init)
    res = training.train(
        train, val, cfg, log=log, progress=runlog.progress(log, f"{cfg.model} {cfg.map_type}"), init_state=init
    )
    checkpoints.save_checkpoint(res, smk.output.checkpoint)
    hist = pd.DataFrame(res["history"])
    io.write_parquet(
        hist,
        smk.output.history,
        {
            "config": cfg.to_dict(),
            "best_epoch": res["best_epoch"],
            "train_proposals": regime,
            "coarse_training": ct if regime == "coarse" else None,
            "warm_start": smk.input.get("init") or None,
            "n_parameters": checkpoints.n_parameters(res["model"]),
            "train_seconds": res["seconds"],
        },
    )
    log.info(
        "best epoch %d, validation median %.2f m, %.1f s, %d parameters",
        res["best_epoch"],
        res["best_val_median_m"],
        res["seconds"],
        checkpoints.n_parameters(res["model"]),
    )


runlog.run(main, snakemake)  # noqa: F821
