"""Rule fine_eval: per-query errors of one run (method x map type x proposal) on the test split.

Methods: ``solver`` (the geometric solver with the training split's priors and, on depth maps,
rule solver_priors' scale prior and verifier) or a trained model checkpoint. Proposals: ``gtbb``
(oracle), ``whole`` (whole reference map), or a coarse proposal table (columns scene, token,
strategy, proposal) filtered on the configured strategy (flatlandia.fine.evaluation).
"""

import numpy as np
import pandas as pd

from flatlandia import io, proposals, runlog, solver
from flatlandia.fine import evaluation


def main(smk, log):
    p, mt = smk.params.p, smk.wildcards.map_type
    strategy = p.get("strategy")  # absent: not a coarse proposal (the params hold what applies only)
    crop_m = float(p.get("crop_m", 0.0))  # absent: not trained on simulated coarse proposals
    method, run = p["method"], f"{smk.wildcards.method}_{mt}_{smk.wildcards.proposal}"
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    coarse = pd.read_parquet(smk.input.coarse) if smk.input.get("coarse") else None
    settings = dict(smk.params.solver)
    model = cfg = None
    if method in ("solver", "solver-noprior"):
        if method == "solver-noprior":  # the solver without the training split's cameras
            settings["camera_prior"] = False
        learned = solver.LearnedPriors.read(smk.input.solver_priors) if smk.input.get("solver_priors") else None
        log.info("learned priors: %s", learned)
        progress = lambda what: runlog.progress(log, what)  # noqa: E731
        errors = evaluation.solver_errors(
            scenes, mt, p["proposal"], settings, learned, coarse, strategy, progress=progress
        )
    else:  # torch only here: the solver's runs start 4 s faster without it
        import torch

        from flatlandia import checkpoints
        from flatlandia import device as device_module
        from flatlandia.fine import learned as models

        torch.set_num_threads(int(smk.threads))
        device = device_module.resolve(smk.config["device"])  # a cuda without a GPU stops here, one line
        log.info("device: %s", device_module.describe(device))
        model, cfg = checkpoints.load_checkpoint(smk.input.checkpoint, models.FineTrainConfig, models.build_model)
        model.to(device)
        errors = evaluation.model_errors(scenes, model, cfg, p["proposal"], coarse, strategy, crop_m)
    errors["strategy"] = p["strategy_label"]
    meta = {
        "run": run,
        "method": method,
        "map_type": mt,
        "proposal": p["proposal"],
        "solver": settings if method.startswith("solver") else None,
        "model_config": cfg.to_dict() if cfg else None,
    }
    io.write_parquet(errors, smk.output.errors, meta)
    summary = evaluation.summarise(errors)
    summary.update(
        method=str(errors["method"].iloc[0]),
        method_slug=method,
        map_type=mt,
        proposal=p["proposal"],
        strategy=p["strategy_label"],
        run=run,
        ref_map_kb=float(np.mean([evaluation.ref_map_kb(ref) for ref, _ in scenes])) if scenes else float("nan"),
        train_s=0.0,
        epochs=0,
        trained_on=proposals.training_label(p.get("train_regime", ""), crop_m),
    )
    if model is not None:
        from flatlandia import checkpoints

        info = checkpoints.checkpoint_info(smk.input.checkpoint)
        summary.update(
            n_parameters=checkpoints.n_parameters(model),
            model_mb=checkpoints.weights_mb(model),
            train_s=float(info.get("seconds") or 0.0),
            epochs=int(cfg.epochs),
        )
    io.write_json(evaluation.json_safe(summary), smk.output.summary)
    log.info("%s: %s", run, summary)


runlog.run(main, snakemake)  # noqa: F821
