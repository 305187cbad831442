"""Benchmark: query recovery of all published scenes (target: under 10 s on 2 cores).

Usage: python benchmarks/bench_recover.py [--root ../shared/flatlandia] [--repeat 3]
Prints per-scene and total wall times of rule recover's entry function
(flatlandia.data.recover.recover_scene), reading the data as the rule does included and excluded.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from flatlandia import config
from flatlandia.classes import CLASSES
from flatlandia.data import published, recover
from flatlandia.plumbing import files

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--root", default=os.environ.get("FLATLANDIA_ROOT", REPO.parent / "shared" / "flatlandia"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    root = Path(args.root)
    tol_m = config.section_defaults("recover")["tol_m"]
    best_total, best_compute = float("inf"), float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        compute, n, per_scene = 0.0, 0, {}
        for scene in sorted(files.read_json(root / "local_maps.json"), key=int):
            # read as rule recover reads them (one job per scene), then its entry function
            lonlat, classes = published.read_reference_map(
                root / f"individual_reference_maps/map_{scene}.json", len(CLASSES)
            )
            local = published.read_local_maps(root / "local_maps.json", scene)
            t1 = time.perf_counter()
            rec = recover.recover_scene(scene, lonlat, classes, local, tol_m=tol_m)
            dt = time.perf_counter() - t1
            assert rec["recovered"].all()
            per_scene[scene] = (len(rec), dt)
            compute += dt
            n += len(rec)
        total = time.perf_counter() - t0
        best_total, best_compute = min(best_total, total), min(best_compute, compute)
    for scene, (k, dt) in per_scene.items():
        print(f"scene {scene:>2}: {k:4d} queries  {dt * 1000:7.1f} ms")
    print(
        f"recovered {n} queries; best of {args.repeat}: registration {best_compute:.2f} s "
        f"({best_compute / n * 1000:.2f} ms/query), with reading the data {best_total:.2f} s"
    )


if __name__ == "__main__":
    main()
