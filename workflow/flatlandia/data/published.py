"""Readers of the published Flatlandia files (classes.tsv, reference maps, local maps, the SfM
transformations, MANIFEST.tsv).

Every reader validates what it returns and raises :class:`InputError` naming the file.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.geo import MIN_OBJECTS
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.files import read_json
from flatlandia.plumbing.names import plain_name


def _need(path: Path) -> Path:
    if not path.exists():
        raise InputError(path, "file is missing")
    if path.is_file() and path.stat().st_size == 0:
        raise InputError(path, "file is empty")
    return path


def read_tsv(path: str | Path, required: list[str]) -> pd.DataFrame:
    path = _need(Path(path))
    try:
        df = pd.read_csv(path, sep="\t", dtype=str, keep_default_na=False)
    except Exception as e:  # pandas raises several types for broken files
        raise InputError(path, f"unreadable TSV: {e}") from e
    missing = [c for c in required if c not in df.columns]
    if missing:
        raise InputError(path, f"missing columns {missing} (has {list(df.columns)})")
    return df


def read_classes(path: str | Path) -> list[str]:
    """The 42 Mapillary Vistas labels; the class id is the row number."""
    df = read_tsv(path, ["class_id", "mapillary_label"])
    ids = df["class_id"].astype(int).tolist()
    if ids != list(range(len(ids))):
        raise InputError(path, "class_id must run 0..N-1 in order")
    return df["mapillary_label"].tolist()


def read_reference_map(path: str | Path, n_classes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A published reference map: ``[[[lon, lat], class_id], ...]`` -> (lonlat (N,2), classes (N,))."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, list) or not data:
        raise InputError(path, "expected a non-empty list of [[lon, lat], class_id]")
    lonlat, classes = np.empty((len(data), 2)), np.empty(len(data), np.int64)
    for i, o in enumerate(data):
        try:
            lonlat[i] = float(o[0][0]), float(o[0][1])
            if isinstance(o[1], bool) or int(o[1]) != o[1]:
                raise ValueError("a class id is a whole number")
            classes[i] = int(o[1])
        except (TypeError, ValueError, IndexError, OverflowError, KeyError):
            shown = repr(o)
            shown = shown if len(shown) <= 60 else shown[:57] + "..."
            raise InputError(path, f"object {i} is {shown}, not [[lon, lat], class_id]") from None
    bad = ~np.isfinite(lonlat).all(axis=1)
    if bad.any():
        raise InputError(
            path, f"{int(bad.sum())} object(s) with NaN/inf coordinates, first at index {int(np.flatnonzero(bad)[0])}"
        )
    if (np.abs(lonlat[:, 0]) > 180).any() or (np.abs(lonlat[:, 1]) > 90).any():
        raise InputError(path, "coordinates outside lon [-180, 180] / lat [-90, 90]")
    if n_classes is not None and ((classes < 0) | (classes >= n_classes)).any():
        raise InputError(path, f"class ids outside 0..{n_classes - 1}")
    return lonlat, classes


def read_local_maps(path: str | Path, scene: str, min_objects: int = MIN_OBJECTS) -> dict[str, dict[str, np.ndarray]]:
    """The published local maps of one scene: token -> {"GT": (M,2), "depth": (M,2)}."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict):
        raise InputError(path, "expected {scene: {token: {GT, depth}}}")
    if scene not in data:
        raise InputError(path, f"unknown scene id {scene!r}; scenes present: {sorted(data, key=_natural)}")
    out: dict[str, dict[str, np.ndarray]] = {}
    if not isinstance(data[scene], dict):
        raise InputError(path, f"scene {scene}: expected {{token: {{GT, depth}}}}")
    for token, maps in data[scene].items():
        plain_name(token, path, f"scene {scene} query token")  # tokens name output files
        try:
            gt = np.asarray(maps["GT"], dtype=float).reshape(-1, 2)
            depth = np.asarray(maps["depth"], dtype=float).reshape(-1, 2)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(path, f"scene {scene} query {token}: malformed local map ({e})") from e
        if len(gt) < min_objects:
            raise InputError(
                path, f"scene {scene} query {token}: local map has {len(gt)} object(s), fewer than {min_objects}"
            )
        if len(depth) != len(gt):
            raise InputError(path, f"scene {scene} query {token}: GT has {len(gt)} objects, depth {len(depth)}")
        if not (np.isfinite(gt).all() and np.isfinite(depth).all()):
            raise InputError(path, f"scene {scene} query {token}: NaN/inf coordinates")
        out[str(token)] = {"GT": gt, "depth": depth}
    return out


def read_transformations(path: str | Path) -> dict:
    path = Path(path)
    t = read_json(path)
    try:
        rpp = np.asarray(t["to_principal_plane"], float)
        r2 = np.asarray(t["to_mapillary"]["rotation"], float)
        s = float(t["to_mapillary"]["scaling_factor_sfm_to_gps"])
        tr = np.asarray(t["to_mapillary"]["translation"], float).reshape(-1)
        float(t["to_flatlandia"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(path, f"malformed transformations ({e})") from e
    if rpp.shape != (3, 3) or r2.shape != (3, 3) or tr.size < 2 or not math.isfinite(s) or s <= 0:
        raise InputError(path, "transformations have wrong shapes or a non-positive scale")
    tf = t["to_flatlandia"]
    for name, a in (("to_principal_plane", rpp), ("to_mapillary.rotation", r2), ("to_mapillary.translation", tr)):
        if not np.isfinite(a).all():
            raise InputError(path, f"{name} holds NaN or inf: the published chain would put objects nowhere")
    if isinstance(tf, bool) or not isinstance(tf, (int, float)) or not math.isfinite(tf) or tf <= 0:
        raise InputError(path, f"to_flatlandia must be a positive finite number, got {tf!r}")
    for name, a in (("to_principal_plane", rpp), ("to_mapillary.rotation", r2)):
        if not np.allclose(a @ a.T, np.eye(3), atol=ROTATION_TOL):
            raise InputError(path, f"{name} is not a rotation or a reflection (its rows are not orthonormal)")
    if np.abs(tr[:2]).max() > 180 or abs(float(tr[1])) > 90:
        raise InputError(path, "to_mapillary.translation is not lon, lat in degrees")
    return t


#: how far a published rotation's rows may be from orthonormal (the published ones: 2e-16)
ROTATION_TOL = 1e-6


def _natural(s: str) -> tuple:
    return (0, int(s)) if s.isdigit() else (1, s)
