"""Learning the solver's verifier from the training split.

Why leave-one-out: a training query's own camera and objects are in the priors, so solving it with
them would make its right hypothesis trivially recognisable. Each training query is solved on its
depth local map with the priors of the *other* training queries, which places it as a test query
is placed (its nearest other training camera is as close as a test query's: median about 1.2 m),
on the region the test queries get (the whole map, or its own GT-BB box: the hypotheses of a
small region differ from those of the whole map), and its refined hypotheses are labelled right
when within (``RIGHT_M``, ``RIGHT_DEG``) of its pose.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

import numpy as np
import pandas as pd

from flatlandia import geo, proposals
from flatlandia.data import localmaps
from flatlandia.solver import distortion, pipeline, priors, scoring, verify
from flatlandia.solver.noise import NoiseModel

#: a hypothesis within this of the true pose is right (the target the verifier is tuned for)
RIGHT_M, RIGHT_DEG = 5.0, 5.0


#: the regions a verifier can learn on: the training queries' own proposals of each kind
REGIONS = {"whole": proposals.whole_map_proposals, "gtbb": proposals.gtbb_proposals}


def scene_groups(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    settings: dict,
    scale_prior,
    region: str = "whole",
    chosen=None,
    noise: NoiseModel | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(features (C, F), right (C,)) of the training queries of one scene (those where ``chosen``,
    a boolean per training query, or all), each solved on its ``region`` with the priors of the
    scene's other training queries and the ``noise`` model (its bearing correction of the scene)."""
    cfg = pipeline.SolverConfig.from_dict(settings)
    whole = priors.camera_priors(ref, queries, settings)
    if whole.cameras is None or whole.seen is None:
        return []
    k = noise.bearing_k(distortion.scene_of(ref)) if noise is not None else 0.0
    whole = replace(whole, scale=scale_prior, noise=noise, bearing_k=k)
    ref_xy, ref_cls = ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    train = queries[queries["split"] == "train"]
    regions = dict(zip(train["token"].astype(str), REGIONS[region](ref, train)["proposal"]))
    groups = []
    for i in range(len(train)) if chosen is None else np.flatnonzero(chosen):
        r = train.iloc[i]
        idx = np.array([pos[int(o)] for o in regions[str(r["token"])] if int(o) in pos], int)
        others = np.arange(len(train)) != i
        pool = pipeline.candidates(
            localmaps.local_map(r, "depth"),
            np.asarray(r["classes"]),
            ref_xy[idx],
            ref_cls[idx],
            metric=False,
            config=cfg,
            priors=whole.without_cameras(others).rows(idx),
            use_verifier=True,
        )
        if pool is None or not pool.verified:
            continue
        data, _, inl, match = scoring.score_terms(pool.problem, pool.priors, pool.t, pool.theta, pool.s)
        f = verify.features(pool.problem, pool.priors, pool.t, pool.theta, pool.s, data, inl, match)
        e_m, e_deg = geo.pose_errors(
            pool.t[:, 0], pool.t[:, 1], pool.theta, r["x_m"], r["y_m"], np.radians(r["theta_deg"])
        )
        ok = np.isfinite(f).all(1)
        groups.append((f[ok], ((e_m < RIGHT_M) & (e_deg < RIGHT_DEG))[ok]))
    return groups


def fit_verifier(
    scenes: Iterable[tuple[pd.DataFrame, pd.DataFrame]],
    settings: dict,
    scale_prior,
    region: str = "whole",
    fraction: float = 1.0,
    rng: np.random.Generator | None = None,
    noise: NoiseModel | None = None,
) -> verify.Verifier | None:
    """The verifier learned from the training split of ``scenes`` (reference map, queries), each
    training query solved on its ``region`` (a key of :data:`REGIONS`): from every training query,
    or from a random ``fraction`` of them drawn with ``rng`` (to measure how much the verifier
    depends on its examples; the priors always hold every training query). None when nothing can
    be learned (no co-visibility sets: ``covis_weight`` 0, or no right hypothesis). ``noise``: the
    depth maps' noise model (:mod:`flatlandia.solver.noise`) the pools are solved with."""
    pipeline.warm_up()
    groups = []
    for ref, q in scenes:
        n = int((q["split"] == "train").sum())
        chosen = None if rng is None else rng.random(n) < fraction
        groups += scene_groups(ref, q, settings, scale_prior, region, chosen, noise)
    return verify.fit(groups) if any(np.any(right) for _, right in groups) else None
