"""Rule fine_eval: per-query errors of one run (method x map type x proposal) on the test split.

Methods: ``solver`` (the geometric solver with the training split's priors and, on depth maps,
rule solver_priors' scale prior and verifier) or a trained model checkpoint. Proposals: ``gtbb``
(oracle), ``whole`` (whole reference map), or a coarse proposal table (columns scene, token,
strategy, proposal) filtered on the configured strategy (flatlandia.fine.evaluation). The config
keys it reads are its params (rules/fine.smk); a key the run does not read is {}.
"""

import numpy as np
import pandas as pd

from flatlandia import proposals, solver, vocabulary
from flatlandia.benchmark import metrics, solver_runs
from flatlandia.fine import evaluation
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    p, w = smk.params, smk.wildcards
    method, mt, proposal = w.method, w.map_type, w.proposal
    key = vocabulary.strategy_key(proposal)
    strategy = str(p[key]) if key else None  # None: not a coarse proposal
    regime = crop_m = None
    if method in vocabulary.LEARNED_METHODS:  # on a coarse proposal: was the model trained on such?
        regime = vocabulary.train_regime(proposal, strategy, bool(key and p["fine.coarse_training.enabled"]))
        crop_m = float(p["fine.coarse_training.crop_m"]) if regime == "coarse" else 0.0
    run = vocabulary.run_name(method, mt, proposal)
    label = vocabulary.strategy_label(proposal, strategy)
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    coarse = pd.read_parquet(smk.input.coarse) if smk.input.get("coarse") else None
    settings = dict(p["solver"])
    model = cfg = None
    if method in vocabulary.SOLVER_METHODS:
        if method == "solver-noprior":  # the solver without the training split's cameras
            settings["camera_prior"] = False
        learned = solver.LearnedPriors.read(smk.input.solver_priors) if smk.input.get("solver_priors") else None
        log.info("learned priors: %s", learned)
        progress = lambda what: rule_log.progress(log, what)  # noqa: E731
        errors = solver_runs.solver_errors(scenes, mt, proposal, settings, learned, coarse, strategy, progress=progress)
    else:  # torch only here: the solver's runs start faster without it (docs/measurements.md, "Start-up costs")
        import torch

        from flatlandia import checkpoints
        from flatlandia import device as device_module
        from flatlandia.fine import models

        torch.set_num_threads(int(smk.threads))
        device = device_module.resolve(smk.config["device"])  # a cuda without a GPU stops here, one line
        log.info("device: %s", device_module.describe(device))
        model, cfg = checkpoints.load_checkpoint(smk.input.checkpoint, models.FineTrainConfig, models.build_model)
        model.to(device)
        errors = evaluation.model_errors(scenes, model, cfg, proposal, coarse, strategy, crop_m)
    errors["strategy"] = label
    meta = {
        "run": run,
        "method": method,
        "map_type": mt,
        "proposal": proposal,
        "solver": settings if method.startswith("solver") else None,
        "model_config": cfg.to_dict() if cfg else None,
    }
    files.write_parquet(errors, smk.output.errors, meta)
    summary = metrics.summarise(errors)
    summary.update(
        method=str(errors["method"].iloc[0]),
        method_slug=method,
        map_type=mt,
        proposal=proposal,
        strategy=label,
        run=run,
        ref_map_kb=float(np.mean([metrics.ref_map_kb(ref) for ref, _ in scenes])) if scenes else float("nan"),
        train_s=0.0,
        epochs=0,
        trained_on=proposals.training_label(regime or "", crop_m or 0.0),
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
    files.write_json(files.json_safe(summary), smk.output.summary)
    log.info("%s: %s", run, summary)


rule_log.run(main, snakemake)  # noqa: F821
