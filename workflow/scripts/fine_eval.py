"""Rule fine_eval: per-query errors of one run (method x map type x proposal) on the test split.

Methods: ``geo`` (the geometric solver, priors and, on depth maps, its verifier from the training
split) or a trained model checkpoint. Proposals: ``gtbb`` (oracle), ``whole`` (whole reference map), or a coarse proposal
table (columns scene, token, strategy, proposal) filtered on the configured strategy; a learned
model trained on simulated coarse proposals gets the real ones cut to their densest objects
(config fine.coarse_training.crop_m), as in its training.
"""

import os

import numpy as np
import pandas as pd

from flatlandia import io, proposals, runlog
from flatlandia.fine import evaluation, solver_verify, solver_verify_fit


def proposals_for(smk, ref, queries, coarse):
    kind = smk.params.p["proposal"]
    if kind == "gtbb":
        return proposals.gtbb_proposals(ref, queries)
    if kind == "whole":
        return proposals.whole_map_proposals(ref, queries)
    scene = str(ref["scene"].iloc[0])
    p = coarse[
        (coarse["scene"].astype(str) == scene)
        & (coarse["strategy"] == smk.params.p["strategy"])
        & (coarse["map_type"] == smk.wildcards.map_type)
    ]
    return p[p["token"].astype(str).isin(queries["token"].astype(str))]


def run_name(smk):
    w = smk.wildcards
    return f"{w.method}_{w.map_type}_{w.proposal}"


def main(smk, log):
    method, mt = smk.params.p["method"], smk.wildcards.map_type
    coarse = pd.read_parquet(smk.input.coarse) if smk.input.get("coarse") else None
    qs = {p: pd.read_parquet(p) for p in smk.input.queries}
    geo_cfg = dict(smk.params.geo)
    refs = {r: pd.read_parquet(r) for r in smk.input.reference_maps}
    scale_prior = verifier = None
    if method == "geo" and mt == "depth":  # the verifier learns on the region the test queries get
        scenes = [(refs[r], qs[q]) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
        scale_prior, verifier = solver_verify_fit.depth_priors(scenes, geo_cfg, smk.params.p["proposal"])
        log.info("depth scale prior (log metres per unit): %s", scale_prior)
        if verifier is not None:
            weights = {f: round(float(w), 3) for f, w in zip(solver_verify.FEATURES, verifier.weights)}
            log.info("solver verifier, weights of the standardised features: %s", weights)
    model = cfg = None
    if method != "geo":  # torch only here: the solver's runs start 4 s faster without it
        import torch

        from flatlandia import checkpoints
        from flatlandia.fine import learned

        torch.set_num_threads(int(smk.threads))
        model, cfg = checkpoints.load_checkpoint(smk.input.checkpoint, learned.FineConfig, learned.build_model)
    parts, map_kb = [], []
    for ref_path, q_path in zip(smk.input.reference_maps, smk.input.queries):
        ref, q = refs[ref_path], qs[q_path]
        map_kb.append(evaluation.ref_map_kb(ref))
        test = q[q["split"] == "test"]
        props = proposals_for(smk, ref, test, coarse)
        if method == "geo":
            prior, seen = evaluation.training_priors(q, geo_cfg)
            parts.append(
                evaluation.evaluate_solver(
                    ref,
                    test,
                    props,
                    mt,
                    geo_cfg,
                    prior_xy=prior,
                    scale_prior=scale_prior,
                    prior_seen=seen,
                    verifier=verifier,
                    method="geometric solver",
                    progress=runlog.progress(log, f"scene {ref['scene'].iloc[0]}"),
                )
            )
        else:  # learned models on coarse proposals see them cut like their training proposals
            parts.append(
                evaluation.evaluate_model(
                    model, cfg, ref, test, proposals.crop_to_densest(ref, props, float(smk.params.p["crop_m"]))
                )
            )
    errors = pd.concat(parts, ignore_index=True)
    errors["strategy"] = smk.params.p["strategy_label"]
    meta = {
        "run": run_name(smk),
        "method": method,
        "map_type": mt,
        "proposal": smk.params.p["proposal"],
        "geo": geo_cfg if method == "geo" else None,
        "model_config": cfg.to_dict() if cfg else None,
    }
    io.write_parquet(errors, smk.output.errors, meta)
    summary = evaluation.summarise(errors)
    summary.update(
        method=str(errors["method"].iloc[0]),
        method_slug=method,
        map_type=mt,
        proposal=smk.params.p["proposal"],
        strategy=smk.params.p["strategy_label"],
        run=run_name(smk),
        ref_map_kb=float(np.mean(map_kb)) if map_kb else float("nan"),
        train_s=0.0,
        epochs=0,
        trained_on=proposals.training_label(smk.params.p["train_regime"], smk.params.p["crop_m"]),
    )
    if model is not None:
        from flatlandia import checkpoints

        info = checkpoints.checkpoint_info(smk.input.checkpoint)
        summary.update(
            n_parameters=checkpoints.n_parameters(model),
            model_mb=os.path.getsize(smk.input.checkpoint) / 1e6,
            train_s=float(info.get("seconds") or 0.0),
            epochs=int(cfg.epochs),
        )
    io.write_json(evaluation.json_safe(summary), smk.output.summary)
    log.info("%s: %s", run_name(smk), summary)


runlog.run(main, snakemake)  # noqa: F821
