"""A folder of geotagged crowd images: metadata (EXIF or CSV), audit table, near-duplicate removal.

Metadata sources, in order of precedence per field:
1. ``metadata.csv`` beside the images (columns ``name`` and any of ``lat, lon, alt, heading,
   capture_time``), for images whose EXIF lacks GPS;
2. the Mapillary ImageDescription JSON (``MAPCompassHeading.TrueHeading``, ``MAPCaptureTime``,
   ``MAPGPSAccuracyMeters``);
3. standard EXIF GPS tags (``GPSLatitude``..., ``GPSImgDirection``) and ``DateTimeOriginal``.
Headings are degrees clockwise from north (compass convention), as the sources give them.

The folder is untrusted: an entry that is not a regular file (a FIFO, a folder, a device) is
dropped without being opened; an image's size is read from its header and the pixels are
decoded only within ``images.max_megapixels`` (and at least ``images.min_side_px``); a
``metadata.csv`` is read with declared types, one error naming its line, column and value.
"""

from __future__ import annotations

import contextlib
import csv as _csv
import difflib
import math
import os
import stat
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from PIL import ExifTags, Image, UnidentifiedImageError
from scipy.spatial.distance import pdist

from flatlandia import config, geo
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.names import plain_name

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
#: the formats PIL may read a photo as, whatever its suffix (no EPS, which PIL renders with Ghostscript)
IMAGE_FORMATS = ("JPEG", "PNG", "TIFF")  # a phone's multi-picture JPEG (MPO) opens as JPEG
GPS_IFD = 0x8825
EXIF_IFD = 0x8769
#: Defaults: the `images` section of workflow/schemas/config.schema.yaml.
_IMAGES = config.section_defaults("images")

#: what a geotag's values can be (degrees, metres); EXIF allows any rational, so a forged or broken
#: tag of latitude 1e9 or heading 1e308 is refused by name rather than used or silently ignored
GEOTAG_RANGES = {"lat": (-90.0, 90.0), "lon": (-180.0, 180.0), "alt": (-1_000.0, 100_000.0), "heading": (-360.0, 360.0)}

#: metadata.csv: its columns (``name`` required) and the ones read as numbers, with their valid range
#: (the geotag's, as EXIF's: an altitude or heading of 1e308 is no more a value in the CSV)
CSV_COLUMNS = ("name", "lat", "lon", "alt", "heading", "capture_time")
CSV_RANGES = dict(GEOTAG_RANGES)


def list_images(folder: str | Path) -> list[Path]:
    """Every entry of ``folder`` with an image suffix, whatever its kind (see :func:`file_problem`)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "image folder does not exist")
    imgs = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not imgs:
        raise InputError(folder, f"no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in the folder")
    return imgs


_FILE_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def file_problem(path: str | Path) -> str | None:
    """Why ``path`` is not a regular file one can read an image from (None: it is), from
    ``os.stat`` alone: nothing is opened (opening a FIFO blocks, a device may never end).
    A symbolic link to a regular file is fine."""
    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        return f"not readable ({e.strerror or e})"
    if stat.S_ISREG(mode):
        return None
    kind = next((what for test, what in _FILE_KINDS if test(mode)), "not a file")
    return f"not a regular file: {kind}"


@contextlib.contextmanager
def open_image(path: str | Path):
    """A PIL image of a regular file, opened lazily: the header (size, EXIF) is read, the pixels
    only on ``load()``. Raises :class:`InputError` for anything but a regular file (checked before
    opening, and again on the open descriptor) and for a file PIL cannot identify as one of
    :data:`IMAGE_FORMATS`. PIL's decompression-bomb check is off here: callers check the size
    against ``images.max_megapixels`` before they decode (:func:`size_problem`)."""
    path = Path(path)
    problem = file_problem(path)
    if problem:
        raise InputError(path, problem)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as e:
        raise InputError(path, f"not readable ({e.strerror or e})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):  # replaced since the check above
            raise InputError(path, "not a regular file")
        saved, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
        try:
            im = Image.open(f, formats=IMAGE_FORMATS)
        except UnidentifiedImageError:
            kinds = f"{', '.join(IMAGE_FORMATS[:-1])} or {IMAGE_FORMATS[-1]}"
            raise InputError(path, f"unreadable image (not a {kinds} image)") from None
        except Exception as e:  # PIL raises many types for files it cannot read
            raise InputError(path, f"unreadable image ({e})") from None
        finally:
            Image.MAX_IMAGE_PIXELS = saved
        with im:
            yield im


def size_problem(width: int, height: int, min_side_px: int, max_megapixels: float) -> str | None:
    """Why an image of this size is refused (None: it is not): a shorter side under
    ``min_side_px`` or more than ``max_megapixels`` million pixels."""
    if min(width, height) < min_side_px:
        return f"smaller than images.min_side_px ({min_side_px} px on the shorter side)"
    if width * height > max_megapixels * 1e6:
        return f"larger than images.max_megapixels ({max_megapixels:g} MP); its pixels were not decoded"
    return None


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


TIME_FORMATS = ("%Y_%m_%d_%H_%M_%S_%f", "%Y:%m:%d %H:%M:%S", "%Y-%m-%dT%H:%M:%S", "%Y-%m-%d %H:%M:%S")


def _parse_time(text: str | None) -> str | None:
    if not text or not isinstance(text, str):
        return None
    for fmt in TIME_FORMATS:
        try:
            return datetime.strptime(text.strip(), fmt).isoformat()
        except ValueError:
            continue
    return None


def _exif_fields(im: Image.Image) -> tuple[dict, dict, dict]:
    """(main, GPS, Exif sub-IFD) tags by name; empty where the EXIF block is malformed (the
    pixels may still be fine: the image then simply carries no metadata)."""
    try:
        exif = im.getexif()
        tags = {ExifTags.TAGS.get(k, k): v for k, v in exif.items()}
        gps = {ExifTags.GPSTAGS.get(k, k): v for k, v in exif.get_ifd(GPS_IFD).items()}
        sub = {ExifTags.TAGS.get(k, k): v for k, v in exif.get_ifd(EXIF_IFD).items()}
    except Exception:  # PIL raises many types for broken EXIF blocks
        return {}, {}, {}
    return tags, gps, sub


def read_exif_metadata(path: str | Path, max_megapixels: float = _IMAGES["max_megapixels"]) -> dict:
    """One image's size and geotag; missing fields are None.

    The size comes from the file's header; the pixels are decoded (so a truncated file fails
    here, not in SfM) only when the image is within ``max_megapixels``: a larger one is returned
    undecoded, for the caller to refuse (:func:`size_problem`). Raises :class:`InputError` for a
    file that is not a regular file or not a readable image."""
    path = Path(path)
    with open_image(path) as im:
        width, height = im.size
        tags, gps, sub = _exif_fields(im)
        if width * height <= max_megapixels * 1e6:
            try:
                im.load()
            except Exception as e:  # PIL raises many types for broken files
                raise InputError(path, f"unreadable image ({e})") from None
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
    mp = _description(path, tags.get("ImageDescription"))
    head = mp.get("MAPCompassHeading", {}) if isinstance(mp.get("MAPCompassHeading"), dict) else {}
    if head.get("TrueHeading") is not None:
        rec["heading"] = _json_number(head.get("TrueHeading"))
    if mp:
        rec["heading_accuracy"] = _float(head.get("AccuracyDegrees"))
    rec["gps_accuracy_m"] = _float(mp.get("MAPGPSAccuracyMeters")) or rec["gps_accuracy_m"]
    rec["capture_time"] = _parse_time(mp.get("MAPCaptureTime")) or rec["capture_time"]
    for key, field in (("lat", "MAPLatitude"), ("lon", "MAPLongitude"), ("alt", "MAPAltitude")):
        if rec[key] is None:
            rec[key] = _json_number(mp.get(field))
    rec["bad_geotag"] = _impossible_geotag(rec)
    return rec


def _description(path: Path, desc) -> dict:
    """The Mapillary JSON of an EXIF ImageDescription ({} when it holds none), parsed through the JSON
    door (:func:`flatlandia.plumbing.validate.parse_json`: depth and number length bounded): a
    description nested 20,000 deep or holding a 5,000-digit number raises :class:`InputError`, and
    the photo is dropped with that reason (the scene's other photos are kept)."""
    if not (isinstance(desc, str) and desc.strip().startswith("{")):
        return {}
    try:
        mp = validate.parse_json(desc, path)
    except InputError as e:
        raise InputError(path, f"its EXIF ImageDescription is not usable JSON ({e.problem})") from None
    return mp if isinstance(mp, dict) else {}


def _json_number(v) -> float | None:
    """A geotag number of the description's JSON: None when absent or not a number, inf kept as inf
    (a 400-digit latitude is impossible, refused by :func:`_impossible_geotag`, not silently unset)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return _float(v)
    return float(v)


def _impossible_geotag(rec: dict) -> dict:
    """The geotag values of ``rec`` outside :data:`GEOTAG_RANGES`, removed from it (field -> value)."""
    bad = {}
    for key, (lo, hi) in GEOTAG_RANGES.items():
        v = rec.get(key)
        if v is not None and not lo <= v <= hi:
            bad[key] = v
            rec[key] = None
    return bad


def _csv_value(csv: Path, line: int, column: str, text: str):
    """One metadata.csv cell as its column's type; None for an empty cell (not given)."""
    text = text.strip()
    if not text:
        return None
    where = f"line {line}, column {column}"
    if column == "capture_time":
        parsed = _parse_time(text)
        if parsed is None:
            examples = " or ".join(repr(datetime(2014, 6, 7, 10, 24, 5).strftime(f)) for f in TIME_FORMATS)
            raise InputError(csv, f"{where}: {text!r} is not a time (write it as EXIF does: {examples})")
        return parsed
    try:
        value = float(text)
    except ValueError:
        raise InputError(csv, f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(csv, f"{where}: {text!r} is not a finite number")
    bounds = CSV_RANGES[column]
    if bounds and not bounds[0] <= value <= bounds[1]:
        raise InputError(csv, f"{where}: {text!r} is outside [{bounds[0]:g}, {bounds[1]:g}]")
    return value


def _csv_header(csv: Path, header: list[str]) -> list[str]:
    header = [c.strip() for c in header]
    if "name" not in header:
        raise InputError(csv, "needs a 'name' column naming each image")
    for col in header:
        if col not in CSV_COLUMNS:
            near = difflib.get_close_matches(col, CSV_COLUMNS, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise InputError(csv, f"line 1: unknown column {col!r}{hint}; valid columns: {', '.join(CSV_COLUMNS)}")
        if header.count(col) > 1:
            raise InputError(csv, f"line 1: column {col!r} appears twice")
    return header


def read_metadata_csv(csv: str | Path, image_names) -> pd.DataFrame:
    """The rows of a folder's ``metadata.csv``, typed and checked, indexed by image name.

    Columns: ``name`` (an image of the folder, once) and any of ``lat, lon`` (degrees, in
    [-90, 90] and [-180, 180]), ``alt`` (metres), ``heading`` (compass degrees), ``capture_time``
    (a time as EXIF writes it). An empty cell means "not given". Every problem raises one
    :class:`InputError` naming the file, the line (as an editor numbers it: the header is line 1),
    the column and the value; an unknown column is refused, naming the valid ones.
    """
    csv = Path(csv)
    problem = file_problem(csv)
    if problem:
        raise InputError(csv, problem)
    folder_names = set(image_names)
    rows, first_line, line = {}, {}, 1
    try:
        with open(csv, newline="", encoding="utf-8-sig") as f:
            reader = _csv.reader(f, strict=True)
            header = _csv_header(csv, next(reader, []))
            for row in reader:
                line = reader.line_num
                if not any(cell.strip() for cell in row):
                    continue  # a blank line
                if len(row) != len(header):
                    raise InputError(
                        csv, f"line {line}: {len(row)} fields, but the header (line 1) has {len(header)}: {row!r}"
                    )
                cells = dict(zip(header, row))
                name = cells["name"].strip()
                try:
                    plain_name(name, csv, "image name")
                except InputError as e:
                    raise InputError(csv, f"{e.problem} (line {line}, column name)") from None
                if name in rows:
                    raise InputError(
                        csv, f"line {line}, column name: image name {name!r} repeats line {first_line[name]}"
                    )
                if name not in folder_names:
                    raise InputError(csv, f"names not in the folder: [{name!r}] (line {line}, column name)")
                rows[name] = {c: _csv_value(csv, line, c, cells[c]) for c in header if c != "name"}
                first_line[name] = line
    except UnicodeDecodeError as e:
        raise InputError(csv, f"line {line}: not UTF-8 text ({e})") from None
    except _csv.Error as e:  # an unclosed quote, a NUL byte, a field over the csv module's size limit
        raise InputError(csv, f"line {reader.line_num}: not valid CSV ({e})") from None
    except OSError as e:
        raise InputError(csv, f"not readable ({e.strerror or e})") from None
    columns = [c for c in header if c != "name"]
    return pd.DataFrame.from_dict(rows, orient="index", columns=columns)


def read_folder_metadata(
    folder: str | Path,
    csv_name: str = "metadata.csv",
    min_side_px: int = _IMAGES["min_side_px"],
    max_megapixels: float = _IMAGES["max_megapixels"],
) -> pd.DataFrame:
    """Metadata of every image of a folder, with ``metadata.csv`` overriding EXIF where given.

    An entry that cannot be used gets its reason in ``problem`` (and is never decoded, or even
    opened when it is not a regular file): not a regular file, unreadable, under ``min_side_px``
    or over ``max_megapixels``."""
    folder = Path(folder)
    recs = []
    for p in list_images(folder):
        try:
            rec = read_exif_metadata(p, max_megapixels)
        except InputError as e:  # one broken file in a crowd folder: drop it, say why
            recs.append({"name": p.name, "problem": e.problem})
            continue
        rec["problem"] = size_problem(rec["width"], rec["height"], min_side_px, max_megapixels)
        recs.append(rec)
    df = pd.DataFrame(recs)
    bad_geotag = dict(zip(df["name"], df["bad_geotag"])) if "bad_geotag" in df.columns else {}
    df = df.drop(columns="bad_geotag", errors="ignore")
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
        "problem",
    ):
        if col not in df.columns:
            df[col] = None
    csv = folder / csv_name
    if os.path.lexists(csv):
        extra = read_metadata_csv(csv, df["name"])
        df = df.set_index("name")
        for col in extra.columns:
            vals = extra[col].reindex(df.index)
            df[col] = vals.where(vals.notna(), df[col])
        df = df.reset_index()
    for col in ("lat", "lon", "alt", "heading"):
        df[col] = df[col].astype(float)
    # an impossible EXIF value that metadata.csv does not replace: the photo is dropped, saying why
    for i, name in enumerate(df["name"]):
        tagged = bad_geotag.get(name)
        bad = {k: v for k, v in tagged.items() if pd.isna(df.at[i, k])} if isinstance(tagged, dict) else {}
        if bad and not (isinstance(df.at[i, "problem"], str) and df.at[i, "problem"]):
            shown = ", ".join(
                f"{k} {v:.6g} outside [{GEOTAG_RANGES[k][0]:g}, {GEOTAG_RANGES[k][1]:g}]" for k, v in bad.items()
            )
            df.at[i, "problem"] = f"impossible geotag in its EXIF ({shown}): give the values in metadata.csv"
    return df


def has_gps(df: pd.DataFrame) -> pd.Series:
    lat, lon = pd.to_numeric(df["lat"], errors="coerce"), pd.to_numeric(df["lon"], errors="coerce")
    return lat.notna() & lon.notna() & (lat.abs() <= 90) & (lon.abs() <= 180)


def thumbnail(path: str | Path, size: tuple[int, int] = (64, 48)) -> np.ndarray:
    with open_image(path) as im:
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


def audit_table(
    folder: str | Path,
    dedup_threshold: float,
    missing_gps: str = _IMAGES["missing_gps"],
    min_side_px: int = _IMAGES["min_side_px"],
    max_megapixels: float = _IMAGES["max_megapixels"],
) -> pd.DataFrame:
    """The images audit table: metadata, kept/dropped and why.

    Entries that are not regular files (a FIFO, a folder, a broken link), unreadable images and
    images under ``min_side_px`` or over ``max_megapixels`` are dropped (the last never decoded).
    Images without a GPS position are kept for SfM but cannot anchor the GPS alignment
    (``missing_gps="keep"``), dropped (``"drop"``), or stop the scene with an error naming them
    (``"stop"``). Near-duplicates of the previous kept image are dropped.
    """
    if missing_gps not in ("keep", "drop", "stop"):
        raise ValueError(f"missing_gps must be keep, drop or stop, not {missing_gps!r}")
    folder = Path(folder)
    df = read_folder_metadata(folder, min_side_px=min_side_px, max_megapixels=max_megapixels)
    for name in df["name"]:  # the names later steps write masks/<name>.png and query files under
        plain_name(name, folder, "image name")
    order = df.sort_values(["capture_time", "name"], na_position="last").index
    df = df.loc[order].reset_index(drop=True)
    df["has_gps"] = has_gps(df)
    df["drop_reason"] = df["problem"].fillna("").astype(str)
    broken = df["drop_reason"] != ""
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
    return df.drop(columns="problem")


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
            "without GPS: none in this scene's align column of the scene sheet, or for every scene --config "
            "'images={align: {mode: none}}'",
        )
