"""Upper bounds of the reference-map reproduction: what any radius could reach.

Usage: python benchmarks/reproduction_bounds.py [--root ../shared/flatlandia] [--scenes 12 14] [--out bounds.parquet]

Per scene of the 12 with a class cloud, published objects of each macro-class against the
clusters of the same colour:
- exact_any_radius: published objects that are the exact mean (1 mm) of a single-linkage cluster
  of >= 3 points at *some* radius (per object; the rest need a split the cloud cannot tell);
- near_any_radius: ... within 0.5 m of one;
- default_0.5m / default_clusters: the workflow's radii (config objects.cluster);
- oracle_0.5m / oracle_0.05m / oracle_clusters: the best single radius per scene and macro-class,
  chosen with the published answer (grid 0.20-2.50 m): no rule that picks one radius per class
  and scene can do better;
- auc_*: on scenes shipping points3D.bin, how well each cluster feature (points, extent, points
  per metre, images observing, median track length) separates the default clusters the published
  map kept (a same-class published object within 0.5 m) from those it dropped (0.5 = not at all).
Reads the published positions: a diagnostic, never used by the workflow to place objects.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from flatlandia import geo
from flatlandia.data import published
from flatlandia.objects import audit, bounds, cloud, clustering
from flatlandia.plumbing import files

REPO = Path(__file__).resolve().parents[1]
SCENES = ["1", "2", "4", "5", "8", "9", "11", "12", "13", "14", "17", "18"]
RADII_M = np.round(np.arange(0.20, 2.501, 0.02), 2)


def scene_bounds(root: Path, scene: str, params: clustering.ClusterParams) -> dict:
    maps = root / "maps" / scene
    pts, labels = cloud.read_classified_cloud(maps / "class_segmented_point_cloud.ply")
    t = published.read_transformations(maps / "transformations.json")
    ref_ll, ref_cl = published.read_reference_map(root / "individual_reference_maps" / f"map_{scene}.json")
    mpu = cloud.metres_per_unit(t)
    frame = geo.frame_for(ref_ll)
    xy, ref_xy = frame.to_xy(geo.sfm_to_lonlat(pts, t)), frame.to_xy(ref_ll)
    fg = labels != cloud.BACKGROUND
    ref_macro = audit.published_macro_classes(
        ref_xy, ref_cl, xy[fg], labels[fg], cloud_points=pts[fg], exact_radius=audit.EXACT_SEARCH_RADIUS_M / mpu
    )
    row = {"scene": scene, "published": len(ref_xy)}
    for k in (
        "exact_any_radius",
        "near_any_radius",
        "default_0.5m",
        "default_clusters",
        "oracle_0.5m",
        "oracle_0.05m",
        "oracle_clusters",
    ):
        row[k] = 0
    members, kept = [], []
    for name in sorted(set(labels[fg])):
        ci = np.flatnonzero(labels == name)
        mine = ref_macro == name
        tree = bounds.single_linkage_tree(pts[ci], xy[ci], max_radius=RADII_M.max() / mpu)
        ex = bounds.exact_objects(tree, ref_xy[mine], tol=1e-3)
        row["exact_any_radius"] += int(ex["exact"].sum())
        row["near_any_radius"] += int((ex["dist"] <= 0.5).sum())

        default = params.eps_for(name)
        default_clusters = clustering._clusters_of_class(pts[ci], mpu, params, default)

        def means(r_m: float, ci=ci, default=default, default_clusters=default_clusters) -> np.ndarray:
            clusters = default_clusters if r_m == default else clustering._clusters_of_class(pts[ci], mpu, params, r_m)
            return np.array([xy[ci[c]].mean(0) for c in clusters]).reshape(-1, 2)

        table = bounds.best_radius_reproduction(means, ref_xy[mine], np.r_[default, RADII_M])
        row["default_0.5m"] += int(table["within_0.5m"].iloc[0])
        row["default_clusters"] += int(table["clusters"].iloc[0])
        best = table.sort_values(["within_0.5m", "clusters"], ascending=[False, True]).iloc[0]
        row["oracle_0.5m"] += int(best["within_0.5m"])
        row["oracle_0.05m"] += int(best["within_0.05m"])
        row["oracle_clusters"] += int(best["clusters"])
        ref_tree = cKDTree(ref_xy[mine]) if mine.any() else None
        for c in default_clusters:
            members.append(ci[c])
            kept.append(ref_tree is not None and bool(ref_tree.query(xy[ci[c]].mean(0))[0] <= 0.5))
    row["oracle_extra"] = row["oracle_clusters"] - row["oracle_0.5m"]
    tracks = maps / "SfM" / "points3D.bin"
    if tracks.is_file():
        sfm_xyz, images = bounds.read_colmap_tracks(tracks)
        d, j = cKDTree(sfm_xyz).query(pts)
        if d.max() < 1e-9:  # the class cloud holds the SfM points: tracks apply point by point
            feats = bounds.cluster_features(members, pts, mpu, [images[k] for k in j])
            row.update({f"auc_{k}": v for k, v in bounds.feature_auc(feats, np.array(kept)).items()})
            row["kept_clusters"], row["dropped_clusters"] = int(np.sum(kept)), int(len(kept) - np.sum(kept))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", default=os.environ.get("FLATLANDIA_ROOT", REPO.parent / "shared" / "flatlandia"))
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--out", help="also write the table as Parquet")
    args = ap.parse_args()
    t0 = time.perf_counter()
    df = pd.DataFrame([scene_bounds(Path(args.root), s, clustering.ClusterParams()) for s in args.scenes])
    pd.set_option("display.width", 250)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    pub = df["published"].sum()
    print(f"\n{len(df)} scenes, {pub} published objects, {time.perf_counter() - t0:.0f} s")
    for k in ("exact_any_radius", "near_any_radius", "default_0.5m", "oracle_0.5m", "oracle_0.05m"):
        print(f"  {k:17s} {df[k].sum():4d}  {df[k].sum() / pub:6.1%}")
    for k in ("default", "oracle"):
        extra = df[f"{k}_clusters"].sum() - df[f"{k}_0.5m"].sum()
        print(f"  {k} extra objects {extra} ({extra / pub:.1%} of published)")
    if args.out:
        files.write_parquet(df, args.out)


if __name__ == "__main__":
    main()
