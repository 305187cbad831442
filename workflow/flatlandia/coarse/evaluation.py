"""Rule coarse_eval: proposals of the coarse retrieval models on the test split, their metrics
and Table 3 (the paper's values in :mod:`flatlandia.paper`).

Region proposals (:func:`propose`): ``N_LM`` (the N best nodes, N = query objects), ``2N_LM``,
``R_30`` (every node within 30 m, true metres, of the best node) and the oracle ``GT-BB``
(:func:`flatlandia.proposals.gtbb_indices`). Metrics per query: precision ``|S n S_gt| / |S|``,
recall ``|S n S_gt| / |S_gt|``, success ``|S n S_gt| >= 3``. Baselines: random scores and the
similarity target itself.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch

from flatlandia import config, paper, proposals, vocabulary
from flatlandia import device as device_module
from flatlandia.coarse import retrieval
from flatlandia.plumbing import escape
from flatlandia.proposals import proposal_metrics  # noqa: F401  (this module's API too)
from flatlandia.report import tables

STRATEGIES = [*vocabulary.COARSE_STRATEGIES, vocabulary.ORACLE_STRATEGY]
#: Defaults: the `coarse.train` section of workflow/schemas/config.schema.yaml (R_30's radius, GT-BB's enlargement).
_TRAIN = config.section_defaults("coarse.train")

#: Columns of results/tables/coarse_localization.parquet: (name, unit, meaning), from its schema.
TABLE_COLUMNS = [(c.name, c.unit, c.meaning) for c in tables.SCHEMAS["coarse_localization"]]


def random_scores(ds: retrieval.Dataset, samples: list[retrieval.Sample], seed: int = 0) -> list[np.ndarray]:
    """The random-scoring baseline: i.i.d. uniform scores per node, seeded."""
    rng = np.random.default_rng(seed)
    return [rng.random(len(ds.refs[s.scene])) for s in samples]


def similarity_scores(samples: list[retrieval.Sample]) -> list[np.ndarray]:
    """Oracle baseline: rank by the target itself (``1 - S``; needs the true GT local map)."""
    return [1.0 - s.S for s in samples]


# ----------------------------------------------------------------------------- proposals and metrics


def propose(
    score: np.ndarray,
    ref_xy: np.ndarray,
    n_query: int,
    strategy: str,
    radius_m: float = _TRAIN["radius_m"],
    matched_rows=None,
    cam_xy=None,
    enlarge: float = _TRAIN["bb_enlarge"],
) -> np.ndarray:
    """Rows of the reference table proposed by a strategy (scores: smaller is better).

    Ties in the score are broken by row (stable sort), so proposals are deterministic.
    """
    score = np.asarray(score, float)
    order = np.argsort(score, kind="stable")
    if strategy == "N_LM":
        return np.sort(order[:n_query])
    if strategy == "2N_LM":
        return np.sort(order[: 2 * n_query])
    if strategy == "R_30":
        best = order[0]
        d = np.linalg.norm(np.asarray(ref_xy, float) - np.asarray(ref_xy, float)[best], axis=1)
        return np.flatnonzero(d <= radius_m)
    if strategy == "GT-BB":
        if matched_rows is None or cam_xy is None:
            raise ValueError("GT-BB needs the matched rows and the true camera")
        return proposals.gtbb_indices(ref_xy, matched_rows, cam_xy, enlarge)
    raise ValueError(f"unknown strategy {strategy!r}; known: {STRATEGIES}")


def evaluate_scores(
    ds: retrieval.Dataset,
    samples: list[retrieval.Sample],
    score_list: list[np.ndarray],
    loss_label: str,
    map_type: str,
    strategies=("N_LM", "2N_LM", "R_30"),
    radius_m: float = _TRAIN["radius_m"],
    enlarge: float = _TRAIN["bb_enlarge"],
) -> pd.DataFrame:
    """One row per (query, strategy): the proposal (reference ``obj_idx``) and its metrics."""
    rows = []
    for s, sc in zip(samples, score_list):
        ref = ds.refs[s.scene]
        xy = ref[["x_m", "y_m"]].to_numpy(float)
        obj = ref["obj_idx"].to_numpy()
        for strat in strategies:
            prop = propose(sc, xy, s.n_objects, strat, radius_m, s.positives, s.cam_xy, enlarge)
            rows.append(
                {
                    "scene": ds.scene_ids[s.scene],
                    "token": s.token,
                    "loss": loss_label,
                    "map_type": map_type,
                    "strategy": strat,
                    "proposal": [int(o) for o in obj[prop]],
                    **proposal_metrics(prop, s.positives),
                }
            )
    return pd.DataFrame(rows)


def summarise(per_query: pd.DataFrame) -> pd.DataFrame:
    """Mean precision / recall / success per (loss, strategy, map type), the paper's beside."""
    g = per_query.groupby(["loss", "strategy", "map_type"], sort=False)
    out = g.agg(
        queries=("token", "size"),
        precision=("precision", "mean"),
        recall=("recall", "mean"),
        success=("success", "mean"),
        proposal_size=("n_proposed", "mean"),
    ).reset_index()
    out["queries"] = out["queries"].astype(np.int64)
    published = [paper.TABLE3.get((r.loss, r.strategy, r.map_type), (np.nan,) * 3) for r in out.itertuples()]
    out["paper_precision"], out["paper_recall"], out["paper_success"] = (
        np.array(published, float).T if published else ([], [], [])
    )
    return out[[c for c, _, _ in TABLE_COLUMNS]]


# ----------------------------------------------------------------------------- evaluation


def evaluate(
    models: dict[str, tuple[retrieval.CoarseGAT, retrieval.CoarseTrainConfig]],
    ds: retrieval.Dataset,
    split: str = "test",
    baselines: bool = True,
    seed: int = 0,
) -> pd.DataFrame:
    """Per-query proposals and metrics of every model x map type x strategy, plus GT-BB and baselines.

    ``models`` maps the loss label (Sim, Trip, Sim+Trip) to (model, config). Baselines: 'random'
    (uniform scores) and 'S oracle' (ranking by the target S, computed from the GT map).
    """
    samples = ds.split(split)
    parts = []
    radius = next(iter(models.values()))[1].radius_m if models else _TRAIN["radius_m"]
    enlarge = next(iter(models.values()))[1].bb_enlarge if models else _TRAIN["bb_enlarge"]
    for label, (model, cfg) in models.items():
        for mt in retrieval.MAP_TYPES:
            parts.append(
                evaluate_scores(
                    ds, samples, retrieval.score_samples(model, ds, samples, mt), label, mt, radius_m=cfg.radius_m
                )
            )
    for mt in retrieval.MAP_TYPES:
        parts.append(
            evaluate_scores(ds, samples, random_scores(ds, samples, seed), "-", mt, ("GT-BB",), radius, enlarge)
        )
        if baselines:
            parts.append(evaluate_scores(ds, samples, random_scores(ds, samples, seed), "random", mt, radius_m=radius))
            if all(s.S is not None for s in samples):
                parts.append(evaluate_scores(ds, samples, similarity_scores(samples), "S oracle", mt, radius_m=radius))
    return pd.concat(parts, ignore_index=True)


def _fmt(p, r, s) -> str:
    return " / ".join("-" if not np.isfinite(v) else f"{v:.3f}" for v in (p, r, s))


def render_markdown(table: pd.DataFrame, title: str = "Coarse map localization (Table 3)", note: str = "") -> str:
    """Rows loss x strategy; columns GT maps and depth maps, ours beside the paper's (P / R / S). The
    rows' labels are escaped (:func:`flatlandia.plumbing.escape.markdown`); ``title`` and ``note`` are the caller's."""
    order_loss = ["-", "Sim", "Trip", "Sim+Trip", "Solver", "random", "S oracle"]
    order_strat = {s: i for i, s in enumerate(STRATEGIES)}
    t = table.copy()
    t["_l"] = t["loss"].map(lambda v: order_loss.index(v) if v in order_loss else len(order_loss))
    t["_s"] = t["strategy"].map(lambda v: order_strat.get(v, 99))
    lines = [f"# {title}", ""]
    if note:
        lines += [note, ""]
    lines += [
        "P / R / S = precision / recall / success (>= 3 correct nodes), test split.",
        "",
        "| loss | NS | GT maps (ours) | GT maps (paper) | depth maps (ours) | depth maps (paper) | queries |",
        "|---|---|---|---|---|---|---|",
    ]
    for (loss, strat), g in t.sort_values(["_l", "_s"]).groupby(["loss", "strategy"], sort=False):
        cells = []
        for mt in retrieval.MAP_TYPES:
            r = g[g["map_type"] == mt]
            if len(r):
                r = r.iloc[0]
                cells += [
                    _fmt(r.precision, r.recall, r.success),
                    _fmt(r.paper_precision, r.paper_recall, r.paper_success),
                ]
            else:
                cells += ["", ""]
        lines.append(
            f"| {escape.markdown(loss)} | {escape.markdown(strat)} | "
            + " | ".join(cells)
            + f" | {int(g['queries'].iloc[0])} |"
        )
    return "\n".join(lines) + "\n"


@torch.no_grad()
def time_one_query(
    model, ds: retrieval.Dataset, sample: retrieval.Sample, map_type: str = "gt", repeats: int = 50
) -> dict:
    """Seconds to score one query against its scene (:func:`fused_scores`, the scene's reference
    embeddings cached, and without the cache: reference graph embedded in the same pass); median
    of ``repeats`` calls."""
    model.eval()
    k = sample.scene
    ref_emb = retrieval.embed(model, ds.ref_graphs[k])
    g = sample.graphs[map_type]
    times = {"score_cached_ref_s": [], "score_with_ref_s": []}
    on_gpu = ref_emb.device.type == "cuda"  # GPU work is queued: wait for it before reading the clock
    for _ in range(repeats):
        t0 = time.perf_counter()
        retrieval.fused_scores(model, None, [g], ref_emb=ref_emb)
        if on_gpu:
            torch.cuda.synchronize()
        t1 = time.perf_counter()
        retrieval.fused_scores(model, ds.ref_graphs[k], [g])
        if on_gpu:
            torch.cuda.synchronize()
        t2 = time.perf_counter()
        times["score_cached_ref_s"].append(t1 - t0)
        times["score_with_ref_s"].append(t2 - t1)
    return {key: float(np.median(v)) for key, v in times.items()}


# ----------------------------------------------------------------------------- rule coarse_eval

#: the graph settings every evaluated model must share (one dataset is built for all of them)
GRAPH_KEYS = ("scale_m", "depth_unit_m", "knn")


@dataclass
class CoarseEvaluation:
    """What rule coarse_eval writes: per loss label its test proposals (per query, map type and
    strategy), Table 3 (:func:`summarise`, the solver's rows included) and the table's note."""

    proposals: dict[str, pd.DataFrame]
    table: pd.DataFrame
    note: str


def evaluate_models(
    models: dict[str, tuple[retrieval.CoarseGAT, retrieval.CoarseTrainConfig]],
    scenes: list[tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]],
    solver_rows: pd.DataFrame,
    seed: int = 0,
    log=None,
    device="cpu",
) -> CoarseEvaluation:
    """Rule coarse_eval: the trained models (loss label -> (model, config)) on the test split of
    every scene's (reference map, queries, similarity target), with the GT-BB, random and S-oracle
    baselines (:func:`evaluate`, seeded), beside the training-free solver's proposals
    (``solver_rows``, rule coarse_solver). The note records the training settings and the time
    to score one query. The models and the test graphs go to ``device`` (a ``torch.device``, or
    the config's ``auto`` | ``cpu`` | ``cuda``) once. Raises ValueError when the models differ in
    :data:`GRAPH_KEYS`."""
    cfgs = [c for _, c in models.values()]
    graphs = [tuple(getattr(c, k) for k in GRAPH_KEYS) for c in cfgs]
    if any(g != graphs[0] for g in graphs):
        raise ValueError(f"the models were trained with different graph settings {GRAPH_KEYS}: {graphs}")
    dev = device_module.torch_device(device)
    models = {label: (model.to(dev), cfg) for label, (model, cfg) in models.items()}
    ds = retrieval.to_device(retrieval.build_dataset(scenes, cfgs[0], splits=("test",)), dev)
    if log is not None:
        log.info("%d test queries over %d scenes; models %s", len(ds.samples), len(scenes), list(models))
    per_query = evaluate(models, ds, "test", baselines=True, seed=int(seed))
    rows = {label: per_query[per_query["loss"] == label].reset_index(drop=True) for label in models}
    table = summarise(pd.concat([per_query, solver_rows], ignore_index=True))
    timing = time_one_query(next(iter(models.values()))[0], ds, ds.samples[0]) if ds.samples else {}
    trained = ", ".join(f"{k}: {c.epochs} epochs" for k, (_, c) in models.items())
    c0 = cfgs[0]
    note = (
        f"Ours: test split of every scene; one model per loss trained on GT and depth maps ({trained}; batch "
        f"{c0.batch_size}, Adam lr {c0.lr:g} {c0.lr_schedule}; triplet negatives {100 * c0.hard_negatives:.0f}% "
        "hardest unmatched, the rest random (paper: all random)). "
        "'Solver': no training, the geometric solver's whole-map poses (config `solver`, training-split priors) "
        "place the query's objects; N_LM / 2N_LM: the objects nearest to them, R_30: every object of the "
        "query's classes within 30 m of them, at the best pose and its near-equal alternatives; BB: the "
        "GT-BB box built from the solver's matches and camera. "
        "'random' scores nodes uniformly at random; 'S oracle' ranks by the Sim target itself (needs the GT map). "
    )
    if timing:
        where = "1 CPU thread" if dev.type == "cpu" else f"on {device_module.describe(dev)}"
        note += (
            f"Scoring one query: {1000 * timing['score_cached_ref_s']:.2f} ms with the scene's reference "
            f"embeddings cached, {1000 * timing['score_with_ref_s']:.2f} ms including them ({where}). "
        )
    if len(solver_rows):
        ms = (1000 * solver_rows.groupby("map_type")["seconds"].median()).to_dict()
        note += "Solver poses of one query (median): " + ", ".join(f"{k} maps {v:.0f} ms" for k, v in ms.items()) + "."
    return CoarseEvaluation(rows, table, note)
