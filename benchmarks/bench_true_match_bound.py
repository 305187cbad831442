"""The true-match bound of depth local maps beside the solver's figures (reads results/ or a copy of it).

    python benchmarks/bench_true_match_bound.py --root results [--split test|val]

The bound: each query's pose refined on its true matches from its true pose (robust Gauss-Newton,
``flatlandia.fine.solver_bound``) with the evidence of each row: bearings only, bearings and
ranges, and with the training-split priors (camera positions and headings, depth scale) too.
Then the solver without the matches: on the whole map and on the GT-BB oracle box (priors and
verifier from the training split, as rule fine_eval has them). Query times of the bound rows are 0.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fine_solver import describe, load, solver_config, solver_errors  # noqa: E402

from flatlandia import (
    geo,  # noqa: E402
    solver,  # noqa: E402
)
from flatlandia.data import localmaps  # noqa: E402
from flatlandia.solver import bound  # noqa: E402


def bound_errors(scenes, split: str, ranges: bool, priors: bool, solver_settings: dict) -> pd.DataFrame:
    """Per-query errors of the true-match refinement, in the solver's error columns."""
    scale_prior = solver.depth_scale_prior([q for _, _, q in scenes], {**solver_settings, "scale_prior": True})
    cfg = solver.SolverConfig.from_dict(solver_settings)
    rows = []
    for _, ref, q in scenes:
        ref_xy = ref[["x_m", "y_m"]].to_numpy()
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"])}
        given = solver.TrainingPriors(solver.priors.training_priors(q, solver_settings)[0], None, scale_prior)
        for r in q[q["split"] == split].itertuples(index=False):
            theta = np.radians(r.theta_deg)
            x, y, th = bound.true_match_pose(
                localmaps.local_map(r, "depth"),
                ref_xy[[pos[int(o)] for o in r.ref_idx]],
                (r.x_m, r.y_m, theta, r.depth_oracle_scale_m),
                ranges,
                cfg,
                given if priors else None,
            )
            e_m, e_deg = geo.pose_errors(x, y, th, r.x_m, r.y_m, theta)
            rows.append({"error_m": e_m, "error_deg": e_deg, "solvable": True, "seconds": 0.0, "cpu_seconds": 0.0})
    return pd.DataFrame(rows)


def main(argv=None):
    import torch

    torch.set_num_threads(1)
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default="results")
    ap.add_argument("--split", default="test")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--set", nargs="*", default=[], help="solver overrides key=value (YAML values)")
    a = ap.parse_args(argv)
    solver_settings = solver_config(a.config, a.set)
    scenes = load(Path(a.root))
    for name, (ranges, priors) in bound.EVIDENCE.items():
        print(
            f"{a.split} true matches, {name}: {describe(bound_errors(scenes, a.split, ranges, priors, solver_settings))}"
        )
    for proposal, label in (("whole", "whole map"), ("gtbb", "GT-BB oracle")):
        t0 = time.perf_counter()
        e = solver_errors(scenes, a.split, "depth", proposal, solver_settings, root=Path(a.root))
        print(f"{a.split} solver, {label}: {describe(e)}; wall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
