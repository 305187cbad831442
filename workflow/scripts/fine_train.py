"""Rule fine_train: one learned fine-localization model (MLP | MLP+ATT | GAT | GAT+ATT) on one map type.

Trains on the train split of every scene with GT-BB proposals, keeps the best-on-validation
weights and saves them with the resolved config (torch.save({'state_dict', 'config', ...})).
"""

import pandas as pd
import torch

from flatlandia import fine, io, runlog
from flatlandia import fine_eval as fe


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    cfg = fine.FineConfig.from_dict({**dict(smk.params.train), "model": smk.params.model,
                                     "map_type": smk.wildcards.map_type})
    train, val = [], []
    for ref_path, q_path in zip(smk.input.reference_maps, smk.input.queries):
        ref, q = pd.read_parquet(ref_path), pd.read_parquet(q_path)
        for split, dest in (("train", train), ("val", val)):
            qs = q[q["split"] == split]
            dest += fine.samples_from_queries(ref, qs, fe.gtbb_proposals(ref, qs), cfg)[0]
    log.info("%s on %s maps: %d train / %d val samples, config %s", cfg.model, cfg.map_type, len(train), len(val),
             cfg.to_dict())
    res = fine.train(train, val, cfg, log=log, progress=runlog.progress(log, f"{cfg.model} {cfg.map_type}"))
    fine.save_checkpoint(res, smk.output.checkpoint)
    hist = pd.DataFrame(res["history"])
    io.write_parquet(hist, smk.output.history, {"config": cfg.to_dict(), "best_epoch": res["best_epoch"],
                                                "n_parameters": fine.n_parameters(res["model"]),
                                                "train_seconds": res["seconds"]})
    log.info("best epoch %d, validation median %.2f m, %.1f s, %d parameters", res["best_epoch"],
             res["best_val_median_m"], res["seconds"], fine.n_parameters(res["model"]))


runlog.run(main, snakemake)  # noqa: F821
