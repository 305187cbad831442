"""Region proposals shared by the coarse and the fine stage.

A proposal table has the columns ``scene, token, strategy, proposal`` (``proposal``: a list of
reference ``obj_idx``); coarse localization writes the same shape (rules coarse_eval and
coarse_solver, the solver's training-free proposals). Here: the oracle GT-BB box
(:func:`gtbb_indices`, :func:`gtbb_proposals`: the reference objects inside the axis-aligned box
around the query's matched objects and the true camera, enlarged 10%), the whole reference map,
and the proposals the learned fine models train on (simulated coarse proposals, cut to their
densest objects like the real ones at evaluation).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import config, vocabulary

PROPOSAL_COLUMNS = ["scene", "token", "strategy", "proposal"]
#: the oracle GT-BB box of the fine stage (the benchmark's definition): enlarged by this share of its
#: size (the coarse stage's GT-BB rows follow the setting `coarse.train.bb_enlarge`, by default the same)
GTBB_ENLARGE = 0.10
#: Defaults: the `fine.coarse_training` section of workflow/schemas/config.schema.yaml.
_COARSE_TRAINING = config.section_defaults("fine.coarse_training")


def gtbb_indices(ref_xy: np.ndarray, matched, cam_xy, enlarge: float = GTBB_ENLARGE) -> np.ndarray:
    """Reference rows inside the box around the matched objects and the camera, enlarged by ``enlarge``."""
    ref_xy = np.asarray(ref_xy, float)
    pts = np.vstack([ref_xy[np.asarray(list(matched), int)], np.asarray(cam_xy, float).reshape(1, 2)])
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * (1 + enlarge)
    return np.flatnonzero(np.all(np.abs(ref_xy - centre) <= half + 1e-9, axis=1))


def gtbb_proposals(ref: pd.DataFrame, queries: pd.DataFrame, enlarge: float = GTBB_ENLARGE) -> pd.DataFrame:
    """The oracle GT-BB proposal of every query (``proposal`` holds reference ``obj_idx``)."""
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    rows = []
    for r in queries.itertuples(index=False):
        rows_idx = [pos[int(i)] for i in r.ref_idx]
        idx = gtbb_indices(ref_xy, rows_idx, [r.x_m, r.y_m], enlarge)
        rows.append(
            {"scene": str(r.scene), "token": str(r.token), "strategy": "GT-BB", "proposal": [int(o) for o in obj[idx]]}
        )
    return pd.DataFrame(rows, columns=PROPOSAL_COLUMNS)


def whole_map_proposals(ref: pd.DataFrame, queries: pd.DataFrame) -> pd.DataFrame:
    """The whole reference map as every query's proposal: the fine stage without a coarse one."""
    obj = [int(o) for o in ref["obj_idx"]]
    return pd.DataFrame(
        [
            {"scene": str(r.scene), "token": str(r.token), "strategy": "whole", "proposal": obj}
            for r in queries.itertuples(index=False)
        ],
        columns=PROPOSAL_COLUMNS,
    )


def for_queries(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    kind: str,
    map_type: str | None = None,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
) -> pd.DataFrame:
    """The proposals of one scene's ``queries`` of a kind: ``gtbb``, ``whole``, or any other kind
    (a coarse stage's) read from ``coarse``, a proposal table with ``map_type`` and ``strategy``
    columns, keeping the rows of this scene, ``map_type`` and ``strategy``."""
    if kind == vocabulary.GTBB:
        return gtbb_proposals(ref, queries)
    if kind == vocabulary.WHOLE:
        return whole_map_proposals(ref, queries)
    if coarse is None:
        raise ValueError(f"proposals {kind!r} need a coarse proposal table")
    scene = str(ref["scene"].iloc[0])
    p = coarse[(coarse["scene"].astype(str) == scene) & (coarse["strategy"] == strategy)]
    if map_type is not None and "map_type" in p.columns:
        p = p[p["map_type"] == map_type]
    return p[p["token"].astype(str).isin(queries["token"].astype(str))]


def simulated_coarse_proposals(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    rng: np.random.Generator,
    recall: float = 0.5,
    size_factor: float = 2.0,
    fp_scale_m: float = 30.0,
) -> pd.DataFrame:
    """Proposals that look like a coarse model's 2N_LM, for training the learned models on them.

    Why: a model trained on GT-BB proposals only has never seen wrong objects, and a coarse
    proposal holds about half. The wrong ones are nearly all of a class the query
    sees and lie near a true one (measured on the real proposals: docs/measurements.md, "Simulated coarse
    proposals"). So each true object is kept with probability ``recall`` (at least one), and wrong objects of
    the query's classes fill ``size_factor`` x N, drawn with weight exp(-d / ``fp_scale_m``), d the
    distance to the nearest true object. Uses ground truth: training split only.
    """
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    rows = []
    for r in queries.itertuples(index=False):
        true = np.array([pos[int(i)] for i in r.ref_idx], int)
        keep = true[rng.random(len(true)) < recall]
        if not len(keep):
            keep = true[rng.integers(len(true), size=1)]
        n_fp = max(int(round(size_factor * len(true))) - len(keep), 0)
        others = np.setdiff1d(np.nonzero(np.isin(ref_cls, np.asarray(r.classes, int)))[0], true)
        if n_fp and len(others):
            d = np.linalg.norm(ref_xy[others, None] - ref_xy[None, true], axis=-1).min(1)
            w = np.exp(-d / fp_scale_m)
            fp = rng.choice(others, size=min(n_fp, len(others)), replace=False, p=w / w.sum())
            keep = np.concatenate([keep, fp])
        rows.append(
            {
                "scene": str(r.scene),
                "token": str(r.token),
                "strategy": "simulated 2N_LM",
                "proposal": [int(o) for o in obj[np.sort(keep)]],
            }
        )
    return pd.DataFrame(rows, columns=PROPOSAL_COLUMNS)


def crop_to_densest(ref: pd.DataFrame, proposals: pd.DataFrame, radius_m: float) -> pd.DataFrame:
    """Each proposal cut down to its objects within ``radius_m`` of its densest object (the one
    with most proposal objects within ``radius_m``; ties to the first).

    Why: a coarse 2N_LM proposal is about half wrong objects scattered over the map, and a learned
    model centres its frame on the proposal, and cropping lowers its error (docs/measurements.md, "Simulated
    coarse proposals").
    ``radius_m <= 0`` returns the proposals unchanged.
    """
    if radius_m <= 0:
        return proposals
    xy = dict(zip(ref["obj_idx"].astype(int), ref[["x_m", "y_m"]].to_numpy()))
    out = []
    for prop in proposals["proposal"]:
        objs = [int(o) for o in prop if int(o) in xy]
        if len(objs) < 2:
            out.append(objs)
            continue
        p = np.array([xy[o] for o in objs])
        near = np.linalg.norm(p[:, None] - p[None], axis=-1) < radius_m
        out.append([o for o, k in zip(objs, near[np.argmax(near.sum(1))]) if k])
    return proposals.assign(proposal=out)


def training_proposals(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    regime: str,
    rng: np.random.Generator,
    copies: int = _COARSE_TRAINING["copies"],
    keep_gtbb: bool = _COARSE_TRAINING["keep_gtbb"],
    crop_m: float = 0.0,
) -> list[pd.DataFrame]:
    """The proposal tables a learned model trains (or validates) on, one sample per query and table.

    ``regime`` ``gtbb``: the oracle GT-BB proposal (the paper's training). ``coarse``: ``copies``
    simulated coarse proposals per query (:func:`simulated_coarse_proposals`, cut by
    :func:`crop_to_densest` to ``crop_m`` like the real ones at evaluation), plus GT-BB when
    ``keep_gtbb``. Why: a model that never saw wrong objects in training does worse on coarse
    proposals (docs/measurements.md, "Simulated coarse proposals"). Uses ground truth: training and
    validation splits only.
    """
    if regime == "gtbb":
        return [gtbb_proposals(ref, queries)]
    if regime != "coarse":
        raise ValueError(f"training proposals must be gtbb or coarse, got {regime!r}")
    out = [gtbb_proposals(ref, queries)] if keep_gtbb else []
    out += [crop_to_densest(ref, simulated_coarse_proposals(ref, queries, rng), crop_m) for _ in range(copies)]
    return out


def training_settings(train: dict, override: dict, coarse_training: dict, regime: str) -> dict:
    """A learned model's training settings (rule fine_train): config fine.train updated by its model's
    fine.train_overrides (e.g. fewer epochs for the slower GATs), and when it trains on simulated
    coarse proposals (``regime`` coarse) by fine.coarse_training.epochs, when set."""
    out = {**train, **override}
    if regime == "coarse" and coarse_training["epochs"]:
        out["epochs"] = coarse_training["epochs"]
    return out


def training_label(regime: str, crop_m: float = 0.0) -> str:
    """How a learned model was trained, for the tables: '' (solver), 'GT-BB' or 'simulated coarse ...'."""
    if not regime:
        return ""
    if regime == "gtbb":
        return "GT-BB"
    return "simulated coarse" + (f", cut to {crop_m:g} m" if crop_m > 0 else "")


def proposal_metrics(proposal, truth) -> dict:
    """Precision, recall, success (>= 3 correct) of one proposal against the matched objects."""
    p, t = set(int(i) for i in proposal), set(int(i) for i in truth)
    hit = len(p & t)
    return {
        "n_proposed": len(p),
        "n_correct": hit,
        "precision": hit / len(p) if p else 0.0,
        "recall": hit / len(t) if t else float("nan"),
        "success": hit >= 3,
    }
