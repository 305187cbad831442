"""Structure from motion with pycolmap (pinned 4.2.1): masked SIFT, matching, mapping, cleaning, BA.

pycolmap's API moves between versions; this module is the only place that calls it for SfM,
and :func:`check_version` refuses an untested one with a clear message.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import config
from flatlandia.images.views import views_from_colmap
from flatlandia.plumbing import escape
from flatlandia.plumbing.errors import InputError
from flatlandia.report import figures

TESTED_PYCOLMAP = "4.2.1"


def check_version() -> None:
    import pycolmap

    if pycolmap.__version__ != TESTED_PYCOLMAP:
        raise RuntimeError(
            f"pycolmap {pycolmap.__version__} is installed, but the SfM stage is tested with "
            f"{TESTED_PYCOLMAP} only (envs/requirements.txt pins it)"
        )


@config.settings("sfm")
class SfmOptions:
    """The SfM stage's settings: the config section ``sfm`` (each key is described in
    config/README.md, ``sfm.*``), plus what the rule fixes per job: the seed (the config's ``seed``)
    and COLMAP's threads (1 when ``deterministic``, else the job's threads)."""

    seed: int = 0
    num_threads: int = 2


def run_sfm(image_dir: Path, image_names: list[str], mask_dir: Path | None, work: Path, opts: SfmOptions, log=print):
    """Extract, match and map; returns the largest reconstruction (pycolmap.Reconstruction)."""
    import pycolmap

    check_version()
    pycolmap.set_random_seed(opts.seed)
    if len(image_names) < 3:
        raise InputError(image_dir, f"SfM needs at least 3 images, {len(image_names)} kept")
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    if db.exists():
        db.unlink()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = opts.camera_model
    if mask_dir is not None:
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = opts.max_image_size
    extraction.num_threads = opts.num_threads
    extraction.sift.max_num_features = opts.max_num_features
    log(f"extracting SIFT features from {len(image_names)} images (masks: {mask_dir})")
    pycolmap.extract_features(
        db,
        image_dir,
        image_names=image_names,
        camera_mode=pycolmap.CameraMode.AUTO,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    log(f"matching ({opts.matcher})")
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = opts.seed
    if opts.matcher == "sequential":
        pycolmap.match_sequential(db, verification_options=verification, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(db, verification_options=verification, device=pycolmap.Device.cpu)
    out = work / "models"
    if out.exists():
        shutil.rmtree(out)
    out.mkdir()
    log(f"mapping ({opts.mapper})")
    if opts.mapper == "incremental":
        o = pycolmap.IncrementalPipelineOptions()
        o.random_seed = opts.seed
        o.num_threads = opts.num_threads
        recs = pycolmap.incremental_mapping(db, image_dir, out, options=o)
    else:
        o = pycolmap.GlobalPipelineOptions()
        o.random_seed = opts.seed
        o.num_threads = opts.num_threads
        recs = pycolmap.global_mapping(db, image_dir, out, options=o)
    if not recs:
        raise InputError(image_dir, "SfM produced no model (too few matches between the images?)")
    best = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    log(f"{len(recs)} model(s); largest has {best.num_reg_images()} images, {best.num_points3D()} points")
    return best


def camera_centres(rec) -> pd.DataFrame:
    rows = [
        {"image_id": int(i), "name": img.name, **dict(zip("xyz", img.projection_center()))}
        for i, img in rec.images.items()
        if img.has_pose
    ]
    return pd.DataFrame(rows)


def height_outliers(centres: np.ndarray, k: float) -> np.ndarray:
    """Cameras far above or below the plane through the others (street level), by a MAD test."""
    c = np.asarray(centres, float)
    if len(c) < 4:
        return np.zeros(len(c), dtype=bool)
    mu = np.median(c, axis=0)
    _, _, vt = np.linalg.svd(c - mu, full_matrices=False)
    h = (c - mu) @ vt[2]
    mad = np.median(np.abs(h - np.median(h))) + 1e-12
    spread = np.median(np.linalg.norm(c - mu, axis=1)) + 1e-12
    return np.abs(h - np.median(h)) > max(k * 1.4826 * mad, 0.05 * spread)


def remove_cameras(rec, image_ids: list[int]) -> None:
    for i in image_ids:
        rec.deregister_frame(rec.images[i].frame_id)


def gps_priors(rec, gps: pd.DataFrame, sigma_m: float = 5.0, alt_sigma_m: float = 10.0):
    """COLMAP pose priors (position only) of the registered images that have GPS.

    Positions are in the metric frame of the images' GPS (``geo.frame_for``: x east, y north,
    altitude up, metres); the horizontal sigma is the image's reported GPS accuracy when
    known. ``gps`` is indexed by image name with lon, lat, alt and optionally gps_accuracy_m.
    Returns (priors, frame) or ([], None) with fewer than 3 geotagged images.
    """
    import pycolmap

    from flatlandia import geo

    rows = [
        (img, gps.loc[img.name])
        for img in rec.images.values()
        if img.has_pose and img.name in gps.index and np.isfinite(gps.loc[img.name, ["lon", "lat"]].astype(float)).all()
    ]
    if len(rows) < 3:
        return [], None
    frame = geo.frame_for(np.array([[float(r["lon"]), float(r["lat"])] for _, r in rows]))
    alts = np.array([float(r["alt"]) if pd.notna(r.get("alt")) else np.nan for _, r in rows])
    alt0 = float(np.nanmedian(alts)) if np.isfinite(alts).any() else 0.0
    priors = []
    for (img, r), alt in zip(rows, alts):
        xy = frame.to_xy(np.array([[float(r["lon"]), float(r["lat"])]]))[0]
        acc = float(r.get("gps_accuracy_m", np.nan)) if pd.notna(r.get("gps_accuracy_m", np.nan)) else sigma_m
        s_alt = alt_sigma_m if np.isfinite(alt) else 1e3  # no altitude: effectively unconstrained
        priors.append(
            pycolmap.PosePrior(
                position=np.array([xy[0], xy[1], alt if np.isfinite(alt) else alt0]),
                position_covariance=np.diag([acc**2, acc**2, s_alt**2]),
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                corr_data_id=img.data_id,
            )
        )
    return priors, frame


def final_bundle_adjustment(
    rec, priors=None, ransac_max_error_m: float = config.section_defaults("images.align")["threshold_m"], seed: int = 0
) -> bool:
    """Bundle adjustment of the cleaned model; with GPS pose priors the model is first aligned to
    them (RANSAC on camera positions) and then refined with their positions as soft constraints,
    so it comes out metric, in the priors' frame. Returns whether priors were used.
    ``ransac_max_error_m``: that alignment's inlier distance, by default the schema's default of
    ``images.align.threshold_m`` (rule sfm does not read the ``images.align`` section)."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.print_summary = False
    if not priors:
        pycolmap.bundle_adjustment(rec, opts)
        return False
    cfg = pycolmap.BundleAdjustmentConfig()
    for iid in rec.reg_image_ids():
        cfg.add_image(iid)
    popts = pycolmap.PosePriorBundleAdjustmentOptions()
    popts.alignment_ransac.max_error = float(ransac_max_error_m)
    popts.alignment_ransac.random_seed = int(seed)
    pycolmap.create_pose_prior_bundle_adjuster(opts, popts, cfg, priors, rec).solve()
    return True


def stats_table(rec, n_input: int, removed: pd.DataFrame) -> pd.DataFrame:
    """One-row summary of the model, plus the removed cameras and why."""
    return pd.DataFrame(
        [
            {
                "images_input": n_input,
                "registered": rec.num_reg_images(),
                "points3D": rec.num_points3D(),
                "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
                "mean_track_length": float(rec.compute_mean_track_length()),
                "removed_cameras": int(len(removed)),
                "removed": "; ".join(f"{r.name}: {r.reason}" for r in removed.itertuples()) if len(removed) else "",
            }
        ]
    )


def _model_plane(cameras: np.ndarray, points: np.ndarray, alignment: dict | None):
    """Cameras and points (N, 3) on the plane the left panel draws, and its axis labels: the map's
    frame when the scene has an alignment record (east/north metres after GPS alignment; without GPS,
    the SfM frame's ground plane, named so), else the cameras' best-fit plane of the SfM frame."""
    from flatlandia import geo

    if alignment is not None:
        cam2, pts2 = geo.alignment_points(alignment, cameras), geo.alignment_points(alignment, points)
        if not geo.alignment_is_local(alignment):
            return cam2, pts2, ("x east (m)", "y north (m)")
        unit = alignment["unit"]
        return cam2, pts2, (f"x, SfM frame's ground plane ({unit})", f"y, SfM frame's ground plane ({unit})")
    mu = np.median(cameras, axis=0)
    _, _, vt = np.linalg.svd(cameras - mu, full_matrices=False)
    labels = ("SfM frame, camera plane axis 1 (SfM units)", "SfM frame, camera plane axis 2 (SfM units)")
    return (cameras - mu) @ vt[:2].T, (points - mu) @ vt[:2].T, labels


def plot_summary(
    cameras: pd.DataFrame,
    points: np.ndarray,
    stats: pd.Series,
    path: Path,
    title: str,
    alignment: dict | None = None,
) -> None:
    """Top view of the model (cameras + points) beside the GPS track. With the scene's alignment
    record (rule gps_alignment) the model is drawn on the map (east/north metres; a scene without
    GPS: its SfM ground plane, labelled so) and the GPS track in the same frame, so the two panels
    compare; without it, on the cameras' plane of the SfM frame (an arbitrary rotation and scale)."""
    plt = figures.pyplot()

    from flatlandia import geo
    from flatlandia.plumbing.files import atomic_path

    cameras = cameras.sort_values("name")  # capture order for Mapillary sequences
    cam2, pts2, labels = _model_plane(
        cameras[["x", "y", "z"]].to_numpy(float), np.asarray(points, float).reshape(-1, 3), alignment
    )
    fig, axes = plt.subplots(1, 2, figsize=(12, 6), dpi=100)
    ax = axes[0]
    ax.scatter(pts2[:, 0], pts2[:, 1], s=1, c="0.6", label=f"{len(pts2)} points")
    ax.plot(cam2[:, 0], cam2[:, 1], "-o", ms=3, c="tab:red", label=f"{len(cam2)} cameras")
    if len(pts2):
        centre = np.median(cam2, axis=0)
        lim = np.percentile(np.abs(np.vstack([cam2, pts2]) - centre), 98) * 1.2
        if lim > 0:
            ax.set_xlim(centre[0] - lim, centre[0] + lim)
            ax.set_ylim(centre[1] - lim, centre[1] + lim)
    ax.set_aspect("equal")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(
        f"SfM model from above: {stats['registered']}/{stats['images_input']} registered, "
        f"{stats['mean_reprojection_error_px']:.2f} px",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    ax = axes[1]
    gps = cameras.dropna(subset=["lat", "lon"])
    if len(gps):
        lonlat = gps[["lon", "lat"]].to_numpy(float)
        frame = geo.alignment_frame(alignment) if alignment is not None else None
        xy = (frame or geo.frame_for(lonlat)).to_xy(lonlat)
        ax.plot(xy[:, 0], xy[:, 1], "-o", ms=3, c="tab:blue", label="GPS (EXIF)")
        if "heading" in gps and gps["heading"].notna().any():
            th = np.radians(90.0 - gps["heading"].to_numpy(float))  # compass -> CCW from east
            ax.quiver(
                xy[:, 0],
                xy[:, 1],
                np.cos(th),
                np.sin(th),
                color="tab:blue",
                alpha=0.6,
                width=0.002,
                angles="xy",
                scale_units="xy",
                scale=0.15,
            )
        if frame is not None:  # the model's frame and view: the aligned cameras beside their fixes
            ax.plot(cam2[:, 0], cam2[:, 1], "o", ms=2, c="tab:red", alpha=0.6, label="SfM cameras, aligned")
            ax.set_xlim(axes[0].get_xlim())
            ax.set_ylim(axes[0].get_ylim())
        ax.legend(fontsize=8)
    else:
        ax.axis("off")
        ax.text(0.5, 0.5, "no GPS positions", ha="center", va="center", transform=ax.transAxes)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title("GPS positions and compass headings", fontsize=9)
    fig.suptitle(escape.mathtext(title))  # the scene id comes from the scene sheet: '$' would start mathtext
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)


# --------------------------------------------------------------------------- rule sfm


def clean_cameras(
    rec, gps: pd.DataFrame, height_mad_k: float, gps_max_residual_m: float, seed: int = 0
) -> pd.DataFrame:
    """Deregister the badly localised cameras of ``rec``; returns them (image_id, name, reason).

    Two tests, in order: cameras off the street-level camera plane (:func:`height_outliers`, MAD
    factor ``height_mad_k``), then, among the others, cameras over ``gps_max_residual_m`` from
    their own GPS fix once the model is aligned to GPS (:func:`flatlandia.images.gps_alignment.gps_outliers`:
    up axes + RANSAC, seeded). ``gps`` is indexed by image name with lon, lat (NaN: no GPS)."""
    from flatlandia.images import gps_alignment

    cams = camera_centres(rec)
    bad = height_outliers(cams[["x", "y", "z"]].to_numpy(), height_mad_k)
    removed = cams.loc[bad, ["image_id", "name"]].assign(reason="off the street-level camera plane")
    views = {v.name: v for v in views_from_colmap(rec)}
    kept = cams.loc[~bad].reset_index(drop=True)
    far = gps_alignment.gps_outliers(
        kept[["x", "y", "z"]].to_numpy(),
        np.array([views[n].R for n in kept["name"]]),
        gps.reindex(kept["name"])[["lon", "lat"]].to_numpy(float),
        float(gps_max_residual_m),
        seed=int(seed),
    )
    reason = f"over {gps_max_residual_m} m from its GPS fix after aligning the model to GPS"
    removed = pd.concat([removed, kept.loc[far, ["image_id", "name"]].assign(reason=reason)])
    remove_cameras(rec, removed["image_id"].tolist())
    return removed


def reconstruct(
    image_dir: Path,
    table: pd.DataFrame,
    mask_dir: Path | None,
    work: Path,
    options: dict,
    seed: int,
    threads: int = 1,
    log=print,
    native_log: str | Path | None = None,
) -> tuple[object, pd.DataFrame, pd.DataFrame]:
    """Rule sfm's model of an images scene -> (pycolmap.Reconstruction, one-row stats, cameras).

    SfM (:func:`run_sfm`) of the kept images of ``table`` (rule image_audit's table: name, kept,
    lon, lat, alt, heading) with their masks, in the scratch folder ``work``; then
    :func:`clean_cameras` and the final bundle adjustment (:func:`final_bundle_adjustment`, with
    the images' GPS as pose priors when ``options['gps_prior']``: the model comes out metric).
    ``options`` is the config's sfm section; COLMAP runs on 1 thread when ``options['deterministic']``,
    else on ``threads``. ``log`` takes one message; what COLMAP prints goes to ``native_log``.
    """
    import pycolmap

    from flatlandia.plumbing import rule_log

    names = list(table.loc[table["kept"], "name"])
    o = dict(options)
    opts = SfmOptions.from_dict(o, seed=seed, num_threads=1 if o["deterministic"] else threads)
    pycolmap.logging.logtostderr = True  # COLMAP's own log, into native_log below
    with rule_log.native_output_to(native_log):
        rec = run_sfm(Path(image_dir), names, None if mask_dir is None else Path(mask_dir), work, opts, log=log)
    gps = table.set_index("name")
    removed = clean_cameras(rec, gps, opts.height_mad_k, o["gps_max_residual_m"], seed=int(seed))
    log(f"removed {len(removed)} badly localised cameras; final bundle adjustment")
    with rule_log.native_output_to(native_log):
        priors, frame = (
            gps_priors(rec, gps, float(o["gps_prior_sigma_m"]), float(o["gps_prior_alt_sigma_m"]))
            if o["gps_prior"]
            else ([], None)
        )
        used = final_bundle_adjustment(rec, priors, seed=int(seed))
    stats = stats_table(rec, len(names), removed)
    stats["gps_prior_images"] = len(priors) if used else 0
    stats["model_frame"] = (
        (f"metric, x east / y north / z up (m) around lon {frame.lon0}, lat {frame.lat0} (aligned to the GPS priors)")
        if used
        else "arbitrary SfM frame (no GPS priors)"
    )
    log("final bundle adjustment " + (f"with {len(priors)} GPS position priors" if used else "without priors"))
    cameras = camera_centres(rec).merge(table[["name", "lat", "lon", "alt", "heading"]], on="name")
    return rec, stats, cameras
