"""The geometric solver's runs of the benchmark: its per-query errors on one scene
(:func:`evaluate_solver`) and on every scene of a split (:func:`solver_errors`), the rows of
:func:`flatlandia.benchmark.metrics.error_row`. Rule fine_eval, the city search's whole-map rows,
the sequences' single frames, the calibration's validation answers and
``benchmarks/bench_fine_solver.py`` all run it so.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from flatlandia import proposals as proposals_module
from flatlandia import solver
from flatlandia.benchmark.metrics import answered, error_row
from flatlandia.data import localmaps
from flatlandia.geo import pose_errors


def solver_errors(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    map_type: str,
    proposal: str,
    settings: dict | None,
    learned: solver.LearnedPriors | None = None,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    split: str = "test",
    every: int = 1,
    progress: Callable[[str], Callable] | None = None,
) -> pd.DataFrame:
    """The fine stage's solver runs, as rule fine_eval and ``benchmarks/bench_fine_solver.py`` run
    them: per-query errors of the ``split`` queries (every ``every``-th) of each scene (reference
    map, queries) on their ``proposal`` (:func:`flatlandia.proposals.for_queries`), with the
    scene's training priors and, for depth maps, the ``learned`` scale prior and verifier.
    ``progress(scene)`` gives a progress wrapper per scene."""
    parts = []
    for ref, q in scenes:
        test = q[q["split"] == split].iloc[::every]
        props = proposals_module.for_queries(ref, test, proposal, map_type, coarse, strategy)
        scene = str(ref["scene"].iloc[0]) if len(ref) else ""
        parts.append(
            evaluate_solver(
                ref,
                test,
                props,
                map_type,
                settings,
                priors=solver.scene_priors(ref, q, settings, learned if map_type == "depth" else None),
                method="geometric solver",
                progress=progress(f"scene {scene}") if progress else None,
            )
        )
    return pd.concat(parts, ignore_index=True)


def evaluate_solver(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    map_type: str,
    config: dict | None = None,
    priors: solver.TrainingPriors | None = None,
    method: str = "solver",
    progress: Callable | None = None,
) -> pd.DataFrame:
    """Run the geometric solver on every query of one scene; one row of errors per query.

    ``proposals`` has the shape scene, token, strategy, proposal (reference obj_idx); queries
    without a proposal row get an empty proposal (counted as failures). ``priors``: the scene's
    training priors over the rows of ``ref`` (:func:`flatlandia.solver.scene_priors`), with the
    learned scale prior and verifier for depth maps; None: none.
    """
    cfg = solver.SolverConfig.from_dict(config)
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    lat = float(ref["lat"].mean())
    props = {str(t): (s, p) for t, s, p in zip(proposals["token"], proposals["strategy"], proposals["proposal"])}
    solver.warm_up()  # query times without the kernels' compilation
    rows = []
    items = list(queries.itertuples(index=False))
    for r in progress(items) if progress else items:
        strategy, prop = props.get(str(r.token), ("none", []))
        idx = np.array([pos[int(o)] for o in prop if int(o) in pos], int)
        q = localmaps.local_map(r, map_type)
        t0, c0 = time.perf_counter(), time.process_time()
        sol = (
            solver.locate(
                q,
                np.asarray(r.classes),
                ref_xy[idx],
                ref_cls[idx],
                metric=(map_type == "gt"),
                config=cfg,
                priors=priors.rows(idx) if priors is not None else None,
            ).best
            if len(idx) >= 2
            else None
        )
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        matched = [-1] * len(q)  # per local-map object, the reference obj_idx it was matched to
        if sol is None:
            pose, errors, fit = (np.nan, np.nan, np.nan), (np.inf, 180.0), (0.0, 0, 0)
        else:
            for k, c in sol.inliers:
                matched[k] = int(obj[idx[c]])
            pose = (sol.x, sol.y, sol.theta)
            errors = pose_errors(sol.x, sol.y, sol.theta, r.x_m, r.y_m, np.radians(r.theta_deg))
            truth = [int(o) for o in r.ref_idx]
            correct = sum(int(obj[idx[c]]) == truth[k] for k, c in sol.inliers)
            fit = (sol.confidence, len(sol.inliers), correct)
        rows.append(
            error_row(
                r,
                method=method,
                map_type=map_type,
                strategy=strategy,
                proposal_classes=ref_cls[idx],
                lat=lat,
                pose=pose,
                errors=errors,
                fit=fit,
                seconds=dt,
                cpu_seconds=dc,
                matches=matched,
                probability=sol.probability if sol is not None else 0.0,
                answered=answered(sol, cfg),
            )
        )
    return pd.DataFrame(rows)
