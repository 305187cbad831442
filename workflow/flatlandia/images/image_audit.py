"""A folder of geotagged crowd images: metadata (EXIF or CSV), audit table, near-duplicate removal.

Metadata sources, in order of precedence per field:
1. ``metadata.csv`` beside the images (columns ``name`` and any of ``lat, lon, alt, heading,
   capture_time``), for images whose EXIF lacks GPS;
2. the Mapillary ImageDescription JSON (``MAPCompassHeading.TrueHeading``, ``MAPCaptureTime``,
   ``MAPGPSAccuracyMeters``);
3. standard EXIF GPS tags (``GPSLatitude``..., ``GPSImgDirection``) and ``DateTimeOriginal``.
Headings are degrees clockwise from north (compass convention), as the sources give them.
"""

from __future__ import annotations

import json
import math
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from PIL import ExifTags, Image
from scipy.spatial.distance import pdist

from flatlandia import geo
from flatlandia.names import plain_name
from flatlandia.errors import InputError

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
GPS_IFD = 0x8825
EXIF_IFD = 0x8769


def list_images(folder: str | Path) -> list[Path]:
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "image folder does not exist")
    imgs = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not imgs:
        raise InputError(folder, f"no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in the folder")
    return imgs


def _dms(value, ref) -> float | None:
    try:
        d, m, s = (float(x) for x in value)
    except (TypeError, ValueError):
        return None
    deg = d + m / 60.0 + s / 3600.0
    return -deg if str(ref).upper() in ("S", "W") else deg


def _float(v) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _parse_time(text: str | None) -> str | None:
    if not text:
        return None
    for fmt in ("%Y_%m_%d_%H_%M_%S_%f", "%Y:%m:%d %H:%M:%S", "%Y-%m-%dT%H:%M:%S", "%Y-%m-%d %H:%M:%S"):
        try:
            return datetime.strptime(text.strip(), fmt).isoformat()
        except ValueError:
            continue
    return None


def read_exif_metadata(path: str | Path) -> dict:
    """One image's size and geotag; missing fields are None."""
    path = Path(path)
    try:
        with Image.open(path) as im:
            width, height = im.size
            exif = im.getexif()
            im.load()  # decode the pixels: a truncated file fails here, not in SfM
    except Exception as e:  # PIL raises many types for broken files
        raise InputError(path, f"unreadable image ({e})") from e
    tags = {ExifTags.TAGS.get(k, k): v for k, v in exif.items()}
    gps = {ExifTags.GPSTAGS.get(k, k): v for k, v in exif.get_ifd(GPS_IFD).items()}
    sub = {ExifTags.TAGS.get(k, k): v for k, v in exif.get_ifd(EXIF_IFD).items()}
    rec = {
        "name": path.name,
        "width": width,
        "height": height,
        "camera": " ".join(str(tags.get(k, "")).strip() for k in ("Make", "Model")).strip() or None,
        "lat": _dms(gps.get("GPSLatitude"), gps.get("GPSLatitudeRef", "N")),
        "lon": _dms(gps.get("GPSLongitude"), gps.get("GPSLongitudeRef", "E")),
        "alt": _float(gps.get("GPSAltitude")),
        "heading": _float(gps.get("GPSImgDirection")),
        "heading_accuracy": None,
        "gps_accuracy_m": _float(gps.get("GPSDOP")),
        "capture_time": _parse_time(sub.get("DateTimeOriginal") or tags.get("DateTime")),
        "focal_35mm": _float(sub.get("FocalLengthIn35mmFilm")),
    }
    desc = tags.get("ImageDescription")
    if isinstance(desc, str) and desc.strip().startswith("{"):
        try:
            mp = json.loads(desc)
        except json.JSONDecodeError:
            mp = {}
        head = mp.get("MAPCompassHeading", {}) if isinstance(mp.get("MAPCompassHeading"), dict) else {}
        rec["heading"] = _float(head.get("TrueHeading")) if head.get("TrueHeading") is not None else rec["heading"]
        rec["heading_accuracy"] = _float(head.get("AccuracyDegrees"))
        rec["gps_accuracy_m"] = _float(mp.get("MAPGPSAccuracyMeters")) or rec["gps_accuracy_m"]
        rec["capture_time"] = _parse_time(mp.get("MAPCaptureTime")) or rec["capture_time"]
        for key, field in (("lat", "MAPLatitude"), ("lon", "MAPLongitude"), ("alt", "MAPAltitude")):
            if rec[key] is None:
                rec[key] = _float(mp.get(field))
    return rec


def read_folder_metadata(folder: str | Path, csv_name: str = "metadata.csv") -> pd.DataFrame:
    """Metadata of every image of a folder, with ``metadata.csv`` overriding EXIF where given."""
    folder = Path(folder)
    recs = []
    for p in list_images(folder):
        try:
            recs.append(read_exif_metadata(p))
        except InputError as e:  # one broken file in a crowd folder: drop it, say why
            recs.append({"name": p.name, "unreadable": e.problem})
    df = pd.DataFrame(recs)
    for col in (
        "width",
        "height",
        "camera",
        "lat",
        "lon",
        "alt",
        "heading",
        "heading_accuracy",
        "gps_accuracy_m",
        "capture_time",
        "focal_35mm",
        "unreadable",
    ):
        if col not in df.columns:
            df[col] = None
    csv = folder / csv_name
    if csv.exists():
        extra = pd.read_csv(csv, dtype={"name": str})
        if "name" not in extra.columns:
            raise InputError(csv, "needs a 'name' column naming each image")
        for name in extra["name"]:
            plain_name(name, csv, "image name")
        unknown = set(extra["name"]) - set(df["name"])
        if unknown:
            raise InputError(csv, f"names not in the folder: {sorted(unknown)[:5]}")
        extra = extra.set_index("name")
        df = df.set_index("name")
        for col in ("lat", "lon", "alt", "heading", "capture_time"):
            if col in extra.columns:
                vals = extra[col].reindex(df.index)
                df[col] = vals.where(vals.notna(), df[col])
        df = df.reset_index()
    return df


def has_gps(df: pd.DataFrame) -> pd.Series:
    lat, lon = pd.to_numeric(df["lat"], errors="coerce"), pd.to_numeric(df["lon"], errors="coerce")
    return lat.notna() & lon.notna() & (lat.abs() <= 90) & (lon.abs() <= 180)


def thumbnail(path: str | Path, size: tuple[int, int] = (64, 48)) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("L").resize(size, Image.Resampling.BILINEAR), dtype=np.float32) / 255.0


def near_duplicates(paths: list[Path], threshold: float) -> list[float]:
    """Mean absolute grey-level difference of each image to the last *kept* one (first: inf).

    An image whose difference is below ``threshold`` is a near-duplicate of its predecessor
    (a phone standing still), as in the paper's low pixel-wise variance test.
    """
    diffs, last = [], None
    for p in paths:
        t = thumbnail(p)
        if last is None or t.shape != last.shape:
            diffs.append(float("inf"))
            last = t
            continue
        d = float(np.mean(np.abs(t - last)))
        diffs.append(d)
        if d >= threshold:
            last = t
    return diffs


def audit_table(folder: str | Path, dedup_threshold: float, missing_gps: str = "keep") -> pd.DataFrame:
    """The images audit table: metadata, kept/dropped and why.

    Unreadable images are dropped. Images without a GPS position are kept for SfM but cannot
    anchor the GPS alignment (``missing_gps="keep"``), dropped (``"drop"``), or stop the scene
    with an error naming them (``"stop"``). Near-duplicates of the previous kept image are dropped.
    """
    if missing_gps not in ("keep", "drop", "stop"):
        raise ValueError(f"missing_gps must be keep, drop or stop, not {missing_gps!r}")
    folder = Path(folder)
    df = read_folder_metadata(folder)
    for name in df["name"]:  # the names later steps write masks/<name>.png and query files under
        plain_name(name, folder, "image name")
    order = df.sort_values(["capture_time", "name"], na_position="last").index
    df = df.loc[order].reset_index(drop=True)
    df["has_gps"] = has_gps(df)
    df["drop_reason"] = ""
    broken = df["unreadable"].notna()
    df.loc[broken, "drop_reason"] = "unreadable image: " + df.loc[broken, "unreadable"].astype(str)
    no_gps = ~df["has_gps"] & ~broken
    if no_gps.any() and missing_gps == "stop":
        raise InputError(
            folder,
            f"images without a GPS position: {list(df.loc[no_gps, 'name'])[:10]} "
            "(set images.missing_gps to keep or drop to go on without them)",
        )
    if missing_gps == "drop":
        df.loc[no_gps, "drop_reason"] = "no GPS position"
    ok = df["drop_reason"] == ""
    diffs = pd.Series(np.nan, index=df.index)
    diffs[ok] = near_duplicates([folder / n for n in df.loc[ok, "name"]], dedup_threshold)
    df["diff_to_previous"] = diffs
    df.loc[ok & (diffs < dedup_threshold), "drop_reason"] = "near-duplicate of previous image"
    df["kept"] = df["drop_reason"] == ""
    return df.drop(columns="unreadable")


#: the GPS alignment fits a similarity (7 parameters, scale included) to the geotagged cameras:
#: it needs at least this many, spread wider than consumer GPS errs (5-10 m)
MIN_GEOTAGGED = 3
MIN_GPS_SPAN_M = 10.0


def check_alignment_inputs(df: pd.DataFrame, folder: str | Path, align_mode: str = "gps") -> None:
    """Stop before any heavy step when the kept images cannot be placed on the map: none kept, or
    (``align_mode`` ``gps``) fewer than :data:`MIN_GEOTAGGED` geotagged ones spread over
    :data:`MIN_GPS_SPAN_M`. A local-frame run (``none``) needs no GPS."""
    kept = df[df["kept"]]
    if kept.empty:
        reasons = df["drop_reason"].value_counts().to_dict()
        raise InputError(folder, f"no image is left after the audit ({len(df)} images; dropped: {reasons})")
    if align_mode == "none":
        return
    tagged = kept[kept["has_gps"]]
    span = 0.0
    if len(tagged) >= 2:
        frame = geo.MetricFrame(float(tagged["lon"].mean()), float(tagged["lat"].mean()))
        span = float(pdist(frame.to_xy(tagged[["lon", "lat"]].to_numpy(float))).max())
    if len(tagged) < MIN_GEOTAGGED or span < MIN_GPS_SPAN_M:
        raise InputError(
            folder,
            f"{len(tagged)} of the {len(kept)} kept images carry a GPS position, spread over {span:.0f} m: "
            f"aligning the model to the map needs at least {MIN_GEOTAGGED} geotagged images more than "
            f"{MIN_GPS_SPAN_M:.0f} m apart. Either give their positions in {Path(folder) / 'metadata.csv'} "
            "(columns name, lat, lon; optional alt, heading, capture_time), or build a local-frame map "
            "without GPS: --config 'images={align: {mode: none}}'",
        )
