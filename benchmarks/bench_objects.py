"""Benchmark: the objects stage on the 12 published class clouds (target: < 2 min on 2 cores).

Usage: python benchmarks/bench_objects.py [--root ../shared/flatlandia]
Runs per scene what rules objects, principal_plane and reproduction_audit run, through their
entry functions (flatlandia.objects.scene_objects.published_objects, principal_plane.published_plane_report,
audit.audit_objects) with the default config. Prints per scene: published objects, ours, matched
within 0.05 / 0.5 / 2 m, median distance, extra objects (ours not within 0.5 m of a published one),
the principal-plane angle to the published one (degrees) and the wall time (read + cluster +
plane + audit), then totals.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import pandas as pd

from flatlandia import config
from flatlandia.data import published
from flatlandia.objects import audit, cloud, principal_plane, scene_objects

REPO = Path(__file__).resolve().parents[1]
SCENES = ["1", "2", "4", "5", "8", "9", "11", "12", "13", "14", "17", "18"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--root", default=os.environ.get("FLATLANDIA_ROOT", REPO.parent / "shared" / "flatlandia"))
    args = ap.parse_args()
    root = Path(args.root)
    cluster = config.section_defaults("objects.cluster")
    plane_cfg = config.section_defaults("objects.principal_plane")
    rows = []
    t_all = time.perf_counter()
    for scene in SCENES:
        t0 = time.perf_counter()
        cloud_path = root / "maps" / scene / "class_segmented_point_cloud.ply"
        pts, labels = cloud.read_classified_cloud(cloud_path)
        t = published.read_transformations(root / "maps" / scene / "transformations.json")
        published_map = published.read_reference_map(root / "individual_reference_maps" / f"map_{scene}.json")
        # labels are not audited: no other scene's map is read for the label transfer
        ours = scene_objects.published_objects(
            scene, pts, labels, t, published_map[0], [], cluster, source=str(cloud_path)
        ).objects
        row, _ = audit.audit_objects(scene, ours, (pts, labels), t, published_map)
        plane = principal_plane.published_plane_report(scene, pts, labels, t, **plane_cfg, source=str(cloud_path))
        row["plane_deg"] = plane["plane_angle_deg"]
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
    total_s = time.perf_counter() - t_all
    df = pd.DataFrame(rows)
    cols = [
        "scene",
        "published",
        "ours",
        "within_0.05m",
        "within_0.5m",
        "within_2m",
        "median_dist_m",
        "extra",
        "plane_deg",
        "seconds",
    ]
    print(df[cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    pub = df["published"].sum()
    for name, sub in (("all 12", df), ("without scene 2", df[df["scene"] != "2"])):
        p = sub["published"].sum()
        print(
            f"{name}: published {p}, ours {sub['ours'].sum()}, within 0.05 m {sub['within_0.05m'].sum() / p:.1%}, "
            f"0.5 m {sub['within_0.5m'].sum() / p:.1%}, 2 m {sub['within_2m'].sum() / p:.1%}, "
            f"extra {sub['extra'].sum() / p:.1%}"
        )
    print(f"max plane angle {df['plane_deg'].max():.2f} deg; {len(df)} scenes ({pub} objects) in {total_s:.1f} s")


if __name__ == "__main__":
    main()
