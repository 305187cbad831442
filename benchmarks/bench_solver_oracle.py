"""Benchmark: the bearing solver's ceiling on depth maps, given the true matches.

Refines each test query's pose on its depth map's bearings with the ground-truth
correspondences (what a perfect hypothesis stage would hand the refinement), and prints the
per-query bearing error of the depth maps. Needs `snakemake all` results (reference maps, queries).
Usage: python benchmarks/bench_solver_oracle.py [--results results]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import bearing_solver, geo, localmaps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--results", default="results")
    args = ap.parse_args()
    errs, bearing = [], []
    for qpath in sorted(Path(args.results).glob("*/queries/queries.parquet")):
        ref = pd.read_parquet(qpath.parent.parent / "maps/reference_map.parquet")
        q = pd.read_parquet(qpath)
        q = q[q["split"] == "test"]
        rxy = ref[["x_m", "y_m"]].to_numpy()
        for r in q.itertuples():
            d, gt = localmaps.xy(r.depth_local_xy), localmaps.xy(r.gt_local_xy_m)
            qb, qr = np.arctan2(d[:, 1], d[:, 0]), np.linalg.norm(d, axis=1)
            x, y, th, _ = bearing_solver._refine(qb, qr, rxy[list(r.ref_idx)], [(k, k) for k in range(len(d))],
                                                 np.array([r.x_m, r.y_m]), np.radians(r.theta_deg),
                                                 r.depth_oracle_scale_m)
            errs.append((np.hypot(x - r.x_m, y - r.y_m), abs(np.degrees(geo.wrap_angle(th - np.radians(r.theta_deg))))))
            bearing.append(np.degrees(np.median(np.abs(geo.wrap_angle(qb - np.arctan2(gt[:, 1], gt[:, 0]))))))
    e = np.array(errs)
    print(f"{len(e)} test queries; refinement with the true matches: median {np.median(e[:, 0]):.2f} m / "
          f"{np.median(e[:, 1]):.2f} deg, within (10 m, 20 deg) {100 * np.mean((e[:, 0] < 10) & (e[:, 1] < 20)):.1f}%")
    print("per-query median bearing error of depth maps (deg), quartiles and 90th percentile:",
          np.percentile(bearing, [25, 50, 75, 90]).round(2))


if __name__ == "__main__":
    main()
