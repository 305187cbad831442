"""Reproduction audit: our objects against the published reference maps (rule reproduction_audit)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import config, geo
from flatlandia.data import published
from flatlandia.objects.cloud import BACKGROUND, macro_of_class, metres_per_unit, read_classified_cloud
from flatlandia.plumbing import escape
from flatlandia.plumbing.files import atomic_path
from flatlandia.report import figures, tables

AUDIT_THRESHOLDS_M = (0.05, 0.5, 2.0)


def published_macro_classes(
    ref_xy: np.ndarray,
    ref_classes: np.ndarray,
    cloud_xy: np.ndarray | None = None,
    cloud_labels: np.ndarray | None = None,
    max_dist_m: float = 2.0,
    cloud_points: np.ndarray | None = None,
    exact_radius: float | None = None,
) -> np.ndarray:
    """Macro-class of each published object: the label of the nearest classified cloud point
    (the objects were made from those points) when one lies within ``max_dist_m``, else the
    macro-class of its 42-class label. With ``cloud_points`` (the same points in SfM
    coordinates) and ``exact_radius`` (SfM units), an object that is the exact mean of a
    single-linkage cluster of one colour takes that colour (its nearest point can be of another:
    scene 2, 16 of 97 objects)."""
    out = macro_of_class(ref_classes)
    if cloud_xy is not None and cloud_labels is not None:
        from scipy.spatial import cKDTree

        fg = np.asarray(cloud_labels, dtype=object) != BACKGROUND
        if fg.any():
            d, j = cKDTree(np.asarray(cloud_xy)[fg]).query(ref_xy)
            near = d <= max_dist_m
            out[near] = np.asarray(cloud_labels, dtype=object)[fg][j[near]]
        if cloud_points is not None and exact_radius is not None:
            from flatlandia.objects.bounds import published_colours

            out = published_colours(
                ref_xy, out, np.asarray(cloud_points, float), cloud_labels, np.asarray(cloud_xy, float), exact_radius
            )
    return out


#: Largest clustering radius (m) searched for the published object an audit object is the mean of.
EXACT_SEARCH_RADIUS_M = 2.5


def audit_scene(
    scene: str,
    ours_xy: np.ndarray,
    ours_macro: np.ndarray,
    ref_xy: np.ndarray,
    ref_macro: np.ndarray,
    radius_m: float = 2.0,
    thresholds: tuple[float, ...] = AUDIT_THRESHOLDS_M,
) -> dict:
    """Match our objects to the published ones (same macro-class, Hungarian on metric distance,
    pairs farther than ``radius_m`` never match) and count the matches within each threshold."""
    from scipy.optimize import linear_sum_assignment

    ours_xy, ref_xy = np.asarray(ours_xy, float).reshape(-1, 2), np.asarray(ref_xy, float).reshape(-1, 2)
    ours_macro, ref_macro = np.asarray(ours_macro, dtype=object), np.asarray(ref_macro, dtype=object)
    dists = []
    for name in sorted(set(ref_macro) | set(ours_macro)):
        a, b = np.flatnonzero(ref_macro == name), np.flatnonzero(ours_macro == name)
        if len(a) == 0 or len(b) == 0:
            continue
        d = np.linalg.norm(ref_xy[a, None] - ours_xy[None, b], axis=2)
        big = radius_m * 10 + d.max() + 1
        r, c = linear_sum_assignment(np.where(d <= radius_m, d, big))
        ok = d[r, c] <= radius_m
        dists.extend(d[r[ok], c[ok]])
    dists = np.array(dists)
    row = {"scene": str(scene), "published": int(len(ref_xy)), "ours": int(len(ours_xy)), "matched": int(len(dists))}
    for t in thresholds:
        row[f"within_{t:g}m"] = int((dists <= t).sum())
    row["median_dist_m"] = float(np.median(dists)) if len(dists) else float("nan")
    t_mid = thresholds[1] if len(thresholds) > 1 else thresholds[0]
    row["extra"] = int(len(ours_xy) - (dists <= t_mid).sum())
    row["frac_within_0.5m"] = row.get("within_0.5m", 0) / max(1, len(ref_xy))
    return row


def audit_objects(
    scene: str,
    ours: pd.DataFrame,
    cloud: tuple[np.ndarray, np.ndarray],
    transformations: dict,
    reference_map: tuple[np.ndarray, np.ndarray],
    radius_m: float = 2.0,
) -> tuple[dict, np.ndarray]:
    """Audit our objects of one published scene -> (row of counts, published objects' metric xy).

    ``ours`` has ``x_m``, ``y_m`` and ``macro_class`` (an objects table or
    :func:`flatlandia.objects.labels.objects_reference_map`); ``cloud`` is the scene's class cloud
    (points, macro-class labels) that gives each published object its macro-class;
    ``reference_map`` is the published (lon/lat, class ids). The metric frame is the published
    map's, as for every other stage.
    """
    pts, labels = cloud
    ref_ll, ref_cl = reference_map
    frame = geo.frame_for(ref_ll)
    fg = labels != BACKGROUND
    ref_xy = frame.to_xy(ref_ll)
    ref_macro = published_macro_classes(
        ref_xy,
        ref_cl,
        frame.to_xy(geo.sfm_to_lonlat(pts[fg], transformations)),
        labels[fg],
        cloud_points=pts[fg],
        exact_radius=EXACT_SEARCH_RADIUS_M / metres_per_unit(transformations),
    )
    row = audit_scene(
        str(scene), ours[["x_m", "y_m"]].to_numpy(), ours["macro_class"].to_numpy(), ref_xy, ref_macro, radius_m
    )
    return row, ref_xy


def audit_published_scene(root: str | Path, scene: str, cluster: dict | None = None) -> tuple[dict, pd.DataFrame]:
    """Run the objects stage on one published scene (:func:`flatlandia.objects.scene_objects.published_objects`,
    config objects.cluster or ``cluster``) and audit it (tests and benchmarks); labels are not
    audited, so no other scene's map is read for them."""
    from flatlandia.objects import scene_objects

    root = Path(root)
    cloud_path = root / "maps" / scene / "class_segmented_point_cloud.ply"
    pts, labels = read_classified_cloud(cloud_path)
    t = published.read_transformations(root / "maps" / scene / "transformations.json")
    ref_ll, ref_cl = published.read_reference_map(root / "individual_reference_maps" / f"map_{scene}.json")
    cluster = config.section_defaults("objects.cluster") if cluster is None else cluster
    ours = scene_objects.published_objects(scene, pts, labels, t, ref_ll, [], cluster, source=str(cloud_path)).objects
    row, _ = audit_objects(scene, ours, (pts, labels), t, (ref_ll, ref_cl))
    return row, ours


#: the counts of a reference_map_reproduction row summed over the scenes into its 'all' row
REPRODUCTION_COUNTS = ["published", "ours", "matched", "within_0.05m", "within_0.5m", "within_2m", "extra"]


def reproduction_table(rows: list[dict], radius_m: float) -> tuple[pd.DataFrame, dict, str]:
    """Rule reproduction_audit's table from its per-scene rows (:func:`audit_objects`): the rows,
    an 'all' row summing them (its median_dist_m is the median of the scenes'), in the columns of
    ``tables.SCHEMAS['reference_map_reproduction']``; also that 'all' row and the table's note."""
    df = pd.DataFrame(rows)
    total = {
        "scene": "all",
        **{c: int(df[c].sum()) for c in REPRODUCTION_COUNTS},
        "median_dist_m": float(df["median_dist_m"].median()) if len(df) else float("nan"),
    }
    total["frac_within_0.5m"] = total["within_0.5m"] / max(1, total["published"])
    df = pd.concat([df, pd.DataFrame([total])], ignore_index=True)
    df = df[[c.name for c in tables.SCHEMAS["reference_map_reproduction"]]]
    note = (
        f"Our objects (clusters of the published class point clouds) matched to the published reference maps, "
        f"same macro-class, Hungarian within {float(radius_m):g} m; 'all' sums the scenes "
        f"(its median_dist_m is the median of the scenes'). Targets: frac_within_0.5m >= 0.9, extra <= 10% of "
        f"published."
    )
    return df, total, note


def plot_audit_grid(panels: list[tuple[str, np.ndarray, np.ndarray]], path: str | Path) -> None:
    """One panel per scene: (title, ours_xy, published_xy), ours (red dots) over theirs (circles)."""
    plt = figures.pyplot()

    n = max(1, len(panels))
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows), dpi=90, squeeze=False)
    for ax in axes.ravel():
        ax.set_visible(False)
    for ax, (title, ours_xy, ref_xy) in zip(axes.ravel(), panels):
        ax.set_visible(True)
        ax.scatter(
            ref_xy[:, 0], ref_xy[:, 1], s=30, facecolor="none", edgecolor="k", label=f"published ({len(ref_xy)})"
        )
        ax.scatter(ours_xy[:, 0], ours_xy[:, 1], s=5, color="tab:red", label=f"ours ({len(ours_xy)})")
        ax.set_aspect("equal")
        ax.set_title(escape.mathtext(title), fontsize=9)
        ax.legend(fontsize=6)
        ax.tick_params(labelsize=6)
    fig.supxlabel("x east (m)")
    fig.supylabel("y north (m)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
