"""Rule queries: the per-scene query table (metric GT local maps, normalised depth maps, split)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import config, geo
from flatlandia.data.localmaps import metric_local_map, normalise_depth_map, oracle_scale, published_to_metric_frame
from flatlandia.plumbing.errors import InputError

#: the columns of queries.parquet, in order (docs/usage.md, "queries.parquet"; docs/tables.md)
QUERY_COLUMNS = [
    "scene",
    "token",
    "n_objects",
    "ref_idx",
    "classes",
    "lon",
    "lat",
    "x_m",
    "y_m",
    "theta_deg",
    "split",
    "gt_local_xy_m",
    "depth_local_xy",
    "depth_oracle_scale_m",
    "residual_m",
    "ambiguous",
    "resolution",
    "n_solutions",
    "second_residual_m",
    "second_cam_dist_m",
]
#: the (train, val, test) shares by default: the schema's `split` section
DEFAULT_FRACTIONS = tuple(config.section_defaults("split")[k] for k in config.SPLIT_KEYS)


def split_queries(
    tokens: list[str], seed: int, fractions: tuple[float, float, float] = DEFAULT_FRACTIONS, salt: str = ""
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
    return pd.DataFrame(rows, columns=QUERY_COLUMNS)


def split_fractions(split: dict) -> tuple[float, float, float]:
    """The (train, val, test) fractions of the config's ``split`` section."""
    return tuple(split[k] for k in config.SPLIT_KEYS)


def published_scene_queries(
    scene: str,
    recovered: pd.DataFrame,
    ref: pd.DataFrame,
    ref_meta: dict,
    local_maps: dict[str, dict[str, np.ndarray]],
    seed: int,
    split: dict,
) -> tuple[pd.DataFrame, dict]:
    """Rule queries on a published scene -> (query table, its Parquet metadata): the recovered
    poses (rule recover) joined with the published local maps in the reference map's metric frame
    (``ref_meta``: the reference map's metadata, lon0/lat0) and a seeded split (config ``seed``
    and ``split``; :func:`split_queries` salted with the scene id)."""
    frame = geo.MetricFrame(ref_meta["lon0"], ref_meta["lat0"])
    labels = split_queries(list(recovered["token"]), seed, split_fractions(split), salt=scene)
    q = build_queries(scene, recovered, ref, local_maps, frame, labels)
    return q, {**ref_meta, "seed": seed, "split": split}
