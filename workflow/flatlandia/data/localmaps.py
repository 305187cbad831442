"""Local maps in metres and the per-scene query table.

Axis convention of every local map we write: camera at the origin, looking along +x, +y to
its left (counter-clockwise), units in metres of the scene's metric frame. ``theta`` is the
heading of the camera's +x axis, counter-clockwise from east, in that metric frame.

Depth local maps are published with an arbitrary per-query scale (depth/GT ratio 0.001-0.01)
in the same degree-unit frame as the GT maps. We carry them into the metric camera frame (so
their bearings are true bearings, see :func:`published_to_metric_frame`) and normalise each
so that the median object range is 1; the least-squares factor to the GT metric map is
stored separately as an *oracle* for analysis.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.data import registration
from flatlandia.errors import InputError


def metric_local_map(ref_xy: np.ndarray, cam_xy: np.ndarray, theta: float) -> np.ndarray:
    """The matched objects (metric frame) seen from the camera: (M, 2) metres."""
    return geo.world_to_local(ref_xy, cam_xy, theta)


def published_to_metric_frame(
    local: np.ndarray, theta_lonlat: float, theta_metric: float, metres_per_degree: tuple[float, float]
) -> np.ndarray:
    """A published local map (degree units, isotropic in lon/lat) in the metric camera frame.

    Published maps live in lon/lat degrees, where east-west is stretched by 1/cos(lat): their
    bearings are not the camera's true bearings. Undo it: camera frame -> lon/lat offsets ->
    metres -> metric camera frame. Applied to a GT map this gives the metric GT map (to within
    the projection's variation over the scene); applied to a depth map it keeps its shape up to
    the unknown scale, with true bearings.
    """
    from flatlandia.data.registration import UNIT_DEG

    offsets_deg = np.asarray(local, float) @ geo.rot2(theta_lonlat).T * UNIT_DEG
    metres = offsets_deg * np.asarray(metres_per_degree, float)
    return metres @ geo.rot2(theta_metric)


def normalise_depth_map(depth: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale a depth local map so its median object range is 1; returns (map, factor)."""
    depth = np.asarray(depth, float)
    med = float(np.median(np.linalg.norm(depth, axis=1)))
    if not np.isfinite(med) or med <= 0:
        return depth.copy(), float("nan")
    return depth / med, 1.0 / med


def oracle_scale(src: np.ndarray, dst: np.ndarray) -> float:
    """Least-squares s minimising ||s*src - dst|| (both in the camera frame)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    den = float(np.sum(src * src))
    return float(np.sum(src * dst) / den) if den > 0 else float("nan")


def split_queries(
    tokens: list[str], seed: int, fractions: tuple[float, float, float] = (0.8, 0.1, 0.1), salt: str = ""
) -> dict[str, str]:
    """Seeded random train/val/test split, independent of input order.

    Tokens are sorted first, then permuted with a generator seeded by (seed, salt) where salt is
    the scene id, so every scene gets its own stable permutation.
    """
    if abs(sum(fractions) - 1.0) > 1e-9:
        raise ValueError(f"split fractions must sum to 1, got {fractions}")
    toks = sorted(set(tokens))
    salt_int = int.from_bytes(salt.encode(), "little") % (2**32) if salt else 0
    rng = np.random.default_rng([int(seed), salt_int])
    order = rng.permutation(len(toks))
    n = len(toks)
    n_train = int(round(fractions[0] * n))
    n_val = int(round(fractions[1] * n))
    labels = np.array(["test"] * n, dtype=object)
    labels[order[:n_train]] = "train"
    labels[order[n_train : n_train + n_val]] = "val"
    return {t: str(labels[i]) for i, t in enumerate(toks)}


def recover_scene(
    scene: str,
    ref_lonlat: np.ndarray,
    ref_classes: np.ndarray,
    local_maps: dict[str, dict[str, np.ndarray]],
    tol_m: float = 0.10,
    progress=None,
) -> pd.DataFrame:
    """Register every GT local map of a scene; one row per query (pose in lon/lat + unit space)."""
    frame = geo.frame_for(ref_lonlat)
    mpd = frame.metres_per_degree()
    index = registration.PairIndex(ref_lonlat / registration.UNIT_DEG)
    rows = []
    items = sorted(local_maps.items())
    for token, maps in progress(items) if progress else items:
        rec = registration.register(maps["GT"], index, mpd, tol_m=tol_m)
        if rec is None:
            rows.append(dict(scene=scene, token=token, recovered=False))
            continue
        best = rec.best
        second = rec.others[0] if rec.others else None
        cam_lonlat = best.cam * registration.UNIT_DEG
        rows.append(
            dict(
                scene=scene,
                token=token,
                recovered=True,
                n_objects=len(maps["GT"]),
                ref_idx=list(best.ref_idx),
                lon=float(cam_lonlat[0]),
                lat=float(cam_lonlat[1]),
                theta_lonlat_deg=float(np.degrees(best.theta)),
                residual_m=best.max_m,
                n_solutions=1 + len(rec.others),
                second_residual_m=second.rms_m if second else float("nan"),
                second_cam_dist_m=float(registration.residual_metres(second.cam - best.cam, mpd))
                if second
                else float("nan"),
                second_ref_idx=list(second.ref_idx) if second else [],
                ambiguous=bool(rec.others),
                resolution=registration.classify_ambiguity(rec, ref_classes),
            )
        )
    return pd.DataFrame(rows)


def build_queries(
    scene: str,
    recovered: pd.DataFrame,
    ref: pd.DataFrame,
    local_maps: dict[str, dict[str, np.ndarray]],
    frame: geo.MetricFrame,
    split: dict[str, str],
) -> pd.DataFrame:
    """Join recovery, metric local maps, depth maps and split into the scene's query table."""
    missing = recovered.loc[~recovered["recovered"].astype(bool), "token"].tolist()
    if missing:
        raise InputError(f"scene {scene}", f"{len(missing)} queries could not be recovered: {missing[:5]}")
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    classes = ref["class_id"].to_numpy()
    mpd = frame.metres_per_degree()
    cams = frame.to_xy(recovered[["lon", "lat"]].to_numpy())
    thetas = frame.heading_to_metric(np.radians(recovered["theta_lonlat_deg"].to_numpy()))
    rows = []
    for k, r in enumerate(recovered.itertuples(index=False)):
        idx = np.asarray(r.ref_idx, int)
        gt = metric_local_map(ref_xy[idx], cams[k], thetas[k])
        depth_metric = published_to_metric_frame(
            local_maps[r.token]["depth"], np.radians(r.theta_lonlat_deg), thetas[k], mpd
        )
        depth_norm, _ = normalise_depth_map(depth_metric)
        rows.append(
            dict(
                scene=scene,
                token=r.token,
                n_objects=len(idx),
                ref_idx=idx.tolist(),
                classes=classes[idx].tolist(),
                lon=r.lon,
                lat=r.lat,
                x_m=float(cams[k][0]),
                y_m=float(cams[k][1]),
                theta_deg=float(np.degrees(thetas[k])),
                split=split[r.token],
                gt_local_xy_m=gt.tolist(),
                depth_local_xy=depth_norm.tolist(),
                depth_oracle_scale_m=oracle_scale(depth_norm, gt),
                residual_m=r.residual_m,
                ambiguous=bool(r.ambiguous),
                resolution=r.resolution,
                n_solutions=int(r.n_solutions),
                second_residual_m=r.second_residual_m,
                second_cam_dist_m=r.second_cam_dist_m,
            )
        )
    return pd.DataFrame(rows)


def xy(cell) -> np.ndarray:
    """A local-map cell (list of [x, y], or the array of arrays Parquet gives back) as (M, 2)."""
    return np.stack([np.asarray(p, dtype=float) for p in cell]).reshape(-1, 2)
