"""Fine 3DoF localization, rule fine_eval: the learned models' per-query errors (the solver's are
:mod:`flatlandia.benchmark.solver_runs`), rows and summaries of :mod:`flatlandia.benchmark.metrics`.
Proposals come as tables of :mod:`flatlandia.proposals`.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from flatlandia import proposals as proposals_module
from flatlandia.benchmark.metrics import error_row
from flatlandia.geo import pose_errors

# torch and torch-geometric load slowly (docs/measurements.md, "Start-up costs"): only the learned
# models' evaluation needs them
if TYPE_CHECKING:
    from torch import nn

    from flatlandia.fine import models


def model_errors(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    model: nn.Module,
    cfg: models.FineTrainConfig,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    crop_m: float = 0.0,
    split: str = "test",
) -> pd.DataFrame:
    """The fine stage's runs of a learned model, as rule fine_eval runs them: per-query errors of
    the ``split`` queries of each scene on their ``proposal``; a model trained on simulated coarse
    proposals (``crop_m`` > 0) sees real ones cut to their densest objects, as in its training."""
    parts = []
    for ref, q in scenes:
        test = q[q["split"] == split]
        props = proposals_module.for_queries(ref, test, proposal, cfg.map_type, coarse, strategy)
        parts.append(evaluate_model(model, cfg, ref, test, proposals_module.crop_to_densest(ref, props, crop_m)))
    return pd.concat(parts, ignore_index=True)


def evaluate_model(
    model: nn.Module,
    cfg: models.FineTrainConfig,
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    method: str | None = None,
) -> pd.DataFrame:
    """Run a learned model on every query of one scene; one row of errors per query (the solver's
    columns). Query time is the single-query inference time (batch of one, after building the
    sample; on the model's device, a GPU: with the copies there and back)."""
    import torch

    from flatlandia import device as device_module
    from flatlandia.fine import models
    from flatlandia.plumbing.pyg import Batch

    samples, kept = models.samples_from_queries(ref, queries, proposals, cfg)
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    strat = dict(zip(proposals["token"].astype(str), proposals["strategy"]))
    lat = float(ref["lat"].mean())
    rows = []
    model.eval()
    device = device_module.model_device(model)
    for s, r in zip(samples, kept.itertuples(index=False)):
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            p = model(Batch.from_data_list([s]).to(device)).cpu().numpy()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x, y, th = models.to_world(p, [s], cfg)[0]
        e_m, e_deg = pose_errors(x, y, th, r.x_m, r.y_m, math.radians(r.theta_deg))
        idx = np.array([pos[int(o)] for o in props.get(str(r.token), []) if int(o) in pos], int)
        rows.append(
            error_row(
                r,
                method=method or cfg.model,
                map_type=cfg.map_type,
                strategy=strat.get(str(r.token), "none"),
                proposal_classes=ref_cls[idx],
                lat=lat,
                pose=(x, y, th),
                errors=(e_m, e_deg),
                fit=(float("nan"), 0, 0),
                seconds=dt,
                cpu_seconds=dc,
            )
        )
    return pd.DataFrame(rows)
