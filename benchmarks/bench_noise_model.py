"""The solver's noise model tuned on the validation split (never the test split): the priors fitted
as rule solver_priors fits them, then the val queries solved with them.

    python benchmarks/bench_noise_model.py --root results [--set key=value ...] [--calibrate]

Prints the fitted noise model, then for the val split (depth maps, whole map): % within (5 m, 5 deg),
whether the pool holds a right pose, and the query CPU median / p90; with ``--calibrate`` also the
answers' calibration fitted as the rule fits it (on these same val answers, so in-sample), the
share answerable at >= 95 % within and the ECE. One CPU thread. Each ``--set`` (YAML values)
overrides a key of the config's ``solver`` section; several ``--grid`` runs are one line each.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia.benchmark import solver_runs  # noqa: E402
from flatlandia.sequences import validation  # noqa: E402
from flatlandia.solver import calibration, learned_priors  # noqa: E402


def load(root: Path) -> list[tuple[pd.DataFrame, pd.DataFrame]]:
    out = []
    for s in sorted((p.name for p in root.iterdir() if p.name.isdigit()), key=int):
        r, q = root / s / "maps/reference_map.parquet", root / s / "queries/queries.parquet"
        if r.exists() and q.exists():
            out.append((pd.read_parquet(r), pd.read_parquet(q)))
    return out


def run(scenes, config: dict, overrides: dict, calibrate: bool) -> str:
    settings = {**config["solver"], **overrides}
    c0 = time.process_time()
    learned = learned_priors.fit(scenes, settings, "whole")
    fit_cpu = time.process_time() - c0
    if calibrate:
        learned, _ = validation.calibrated(scenes, settings, learned, "whole", None, int(config["seed"]))
        learned, _ = validation.with_null(scenes, settings, learned, "whole", int(config["seed"]))
    e = solver_runs.solver_errors(scenes, "depth", "whole", settings, learned, split="val")
    em, ed = e["error_m"].to_numpy(float), e["error_deg"].to_numpy(float)
    right = (em < 5) & (ed < 5)
    ms = 1000 * e["cpu_seconds"].quantile([0.5, 0.9])
    line = (
        f"{' '.join(f'{k}={v}' for k, v in overrides.items()) or 'defaults'}: within {100 * right.mean():.1f} %, "
        f"median {np.nanmedian(em):.2f} m; CPU {ms.loc[0.5]:.1f} / {ms.loc[0.9]:.1f} ms; priors fit {fit_cpu:.0f} s CPU"
    )
    if calibrate:
        p = e["probability"].to_numpy(float)
        line += (
            f"; answerable at >= 95 % {calibration.largest_coverage(p, ~right, 5.0):.1f} %, "
            f"ECE {calibration.expected_calibration_error(p, right):.1f}"
        )
    n = getattr(learned, "noise", None)
    return line + (
        f"\n    noise: bearing {[round(v, 2) for v in n.bearing_sigma_deg]} deg, log range "
        f"{[round(v, 3) for v in n.log_range_sigma]}"
        if n is not None
        else ""
    )


def main(argv=None) -> int:
    import torch

    torch.set_num_threads(1)
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default="results")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--set", nargs="*", default=[], help="solver overrides key=value (YAML values)")
    ap.add_argument(
        "--grid", nargs="*", default=[], help="several runs, each 'k=v,k=v' (on top of --set), one line each"
    )
    ap.add_argument("--calibrate", action="store_true", help="also fit the calibration and report answerable / ECE")
    a = ap.parse_args(argv)
    config = yaml.safe_load(open(a.config))
    scenes = load(Path(a.root))
    base = {k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in a.set)}
    runs = [base] + [
        {**base, **{k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in g.split(","))}} for g in a.grid
    ]
    for over in runs if a.grid else [base]:
        print(run(scenes, config, over, a.calibrate), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
