"""Checks at the doors: what a file read from outside a run must be before any code uses it.

Why one module: the files a user or a download controls (a query or sequence JSON, a map Parquet
or GeoJSON, a city index ``.npz``, a priors JSON, a poses CSV or Parquet, a provenance record)
reach numba kernels, pyproj and torch, which do not check what they are given: a pointer out of
range is a segfault, a NaN a silently wrong pose, a size nobody bounded an hour of CPU or all the
memory. Every reader calls the checks here before the data is used, and each failed check is one
:class:`~flatlandia.plumbing.errors.InputError` naming the file and the problem.

The bounds are named constants, all of them here (docs/security.md says why each has its value and
what its worst input cost, measured). Each is far above what the benchmark's own files need (noted
beside it).
"""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np

from flatlandia.plumbing.errors import InputError

MB = 1_000_000

# ----------------------------------------------------------------------------- bounds

#: any JSON file the workflow reads (the published local_maps.json: 1.1 MB)
MAX_JSON_BYTES = 64 * MB
#: a query or sequence file of ``flatlandia localize`` (a query of 17 objects: under 2 kB)
MAX_QUERY_JSON_BYTES = 8 * MB
#: nesting of any JSON value (a query file needs 4 levels, a provenance record 4, a checkpoint's config 3)
MAX_JSON_DEPTH = 32
#: nesting of a config value (the schema's deepest key: 4 levels; Snakemake's own YAML loader
#: fails on its own far deeper: docs/security.md, "The bounds")
MAX_CONFIG_DEPTH = 16
#: digits of a JSON integer read as an integer (longer ones are read as floats, so 10**400 is inf)
MAX_INT_DIGITS = 30
#: objects of one query (the published local maps hold at most 17; far more ran for minutes:
#: docs/security.md, "The bounds")
MAX_QUERY_OBJECTS = 100
#: queries of one query file (the benchmark's test split: 215)
MAX_QUERIES = 10_000
#: frames of one sequence (the benchmark's sequences: 5; the cost grows with the frames: docs/security.md, "The bounds")
MAX_SEQUENCE_FRAMES = 20
#: largest coordinate of a query's local map, any unit (metres of a GT map: a camera sees 100 m)
MAX_LOCAL_COORD = 1e6
#: largest odometry step of a sequence frame from the anchor, metres (a scene is under 1 km across)
MAX_ODOMETRY_M = 10_000.0
#: largest GPS sigma or search radius, metres (a phone's fix: 3-50 m; a city: 20 km)
MAX_PRIOR_M = 1_000_000.0
#: largest compass sigma, degrees (beyond half a turn a compass says nothing)
MAX_COMPASS_SIGMA_DEG = 180.0
#: objects of a scene map file (a scene: about 120; the solver's time grows with the map,
#: docs/security.md, "The bounds": a larger map is a city, searched through its index)
MAX_MAP_OBJECTS = 20_000
#: objects of one class in a scene map (a published scene: at most 86): the solver's candidates, and
#: its time, grow with it (docs/security.md, "The bounds")
MAX_CLASS_OBJECTS = 300
#: objects of a city index (the simulated city: 100,000)
MAX_INDEX_OBJECTS = 1_000_000
#: a map file on disk (Parquet, GeoJSON; a scene's: 10-60 kB)
MAX_MAP_BYTES = 256 * MB
#: a city index: the ``.npz`` on disk and its arrays once unpacked (the 20-scene city's: 0.2 MB)
MAX_INDEX_BYTES = 256 * MB
#: a poses file, on disk and (a compressed CSV) once decompressed (215 test queries x 12 settings: 0.3 MB)
MAX_POSES_BYTES = 64 * MB
#: rows of a poses file (every query of 20 scenes in 12 settings: 26,000)
MAX_POSES_ROWS = 200_000
#: a CSV of an export read back (``localize --batch``; the export's largest, proposals.csv: 12 MB for
#: every scene, a scene's under 2 MB)
MAX_CSV_BYTES = 64 * MB
#: a checkpoint file (the default run's largest: 0.6 MB; the paper's GAT: 3 MB)
MAX_CHECKPOINT_BYTES = 256 * MB
#: a provenance record (the default run's largest: 40 kB)
MAX_RECORD_BYTES = 16 * MB
#: a map's lon0/lat0 (its metric frame's origin) may lie this far from its objects' centre, metres
MAX_ORIGIN_OFFSET_M = 50_000.0
#: a map's x_m/y_m must be its lon/lat projected in its own frame to within this, metres
FRAME_TOLERANCE_M = 1.0
#: characters of a value quoted in an error message (a 100 MB token is shown by its start)
SHOW_CHARS = 80


# ----------------------------------------------------------------------------- messages


def shown(value: Any, limit: int = SHOW_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (with how long it was): an error line quotes
    what it refuses without echoing a 100 MB value."""
    if isinstance(value, str) and len(value) > 4 * limit:
        value = value[: 4 * limit]  # repr of a huge string is never built
        text = repr(value)[:limit]
        return f"{text}... (a text longer than {4 * limit} characters)"
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


# ----------------------------------------------------------------------------- files


def regular_file(path: str | Path, max_bytes: int | None = None, limit_name: str = "") -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a regular file of at most ``max_bytes``; a folder,
    a named pipe, a device or a socket is refused without being opened (a FIFO would block the
    reader, ``/dev/zero`` never ends), and so is a file over the bound (``limit_name`` names it)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(path, "file is missing") from None
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(path, "is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(path, "is not a regular file (a named pipe, a device or a socket): refused without reading it")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputError(path, f"{st.st_size:,} bytes, over the limit of {max_bytes:,}{_named(limit_name)}")
    return st


def _named(limit_name: str) -> str:
    return f" (flatlandia.plumbing.validate.{limit_name})" if limit_name else ""


def read_bytes(path: str | Path, max_bytes: int, limit_name: str = "") -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (:func:`regular_file`), read without
    ever holding more than that: a file that grows while it is read, or was swapped for a pipe
    after the check, is refused too (opened non-blocking, checked again on the open file)."""
    regular_file(path, max_bytes, limit_name)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or e})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputError(path, "is not a regular file: refused without reading it")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputError(path, f"over the limit of {max_bytes:,} bytes{_named(limit_name)}")
    return data


def read_decompressed(path: str | Path, opener, max_bytes: int, limit_name: str = "") -> bytes:
    """The decompressed bytes of a compressed regular file (``opener``: gzip.open, bz2.open,
    lzma.open), streamed and stopped as soon as they pass ``max_bytes``: a 4 MB archive of 2 GB
    is refused after reading ``max_bytes``, never holding more."""
    regular_file(path, max_bytes, limit_name)
    out, n = [], 0
    try:
        with opener(path, "rb") as f:
            while chunk := f.read(1 << 20):
                n += len(chunk)
                if n > max_bytes:
                    raise InputError(
                        path, f"decompresses to over {max_bytes:,} bytes, over the limit{_named(limit_name)}"
                    )
                out.append(chunk)
    except InputError:
        raise
    except (OSError, EOFError, ValueError) as e:  # gzip.BadGzipFile, lzma.LZMAError, ...
        raise InputError(path, f"not a readable compressed file ({type(e).__name__}: {e})") from None
    return b"".join(out)


def parquet_size(
    path: str | Path, max_rows: int, max_bytes: int, what: str = "rows", names: tuple[str, str] = ("", "")
) -> int:
    """Before a Parquet file is read: a regular file of at most ``max_bytes`` whose footer declares
    at most ``max_rows`` rows and at most ``max_bytes`` once uncompressed (its row groups' sizes);
    its number of rows. A file that is not Parquet raises pyarrow's error (each caller words it)."""
    import pyarrow.parquet as pq

    regular_file(path, max_bytes, names[1])
    meta = pq.ParquetFile(path).metadata  # a file that is not Parquet: pyarrow's error, the caller's message
    count(meta.num_rows, max_rows, path, what, names[0] or "a bound")
    raw = sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))
    if raw > max_bytes:
        raise InputError(
            path, f"its columns unpack to {raw:,} bytes, over the limit of {max_bytes:,}{_named(names[1])}"
        )
    return meta.num_rows


# ----------------------------------------------------------------------------- JSON


def _int_or_float(text: str):
    """A JSON integer: Python's int up to :data:`MAX_INT_DIGITS` digits, else a float (``10**400``
    becomes inf, refused where a finite number is needed; int() of 4,300 digits would raise)."""
    return int(text) if len(text) <= MAX_INT_DIGITS else float(text)


def depth(value: Any, limit: int = MAX_JSON_DEPTH) -> int:
    """How deeply ``value`` (parsed JSON or YAML) nests, without recursion (counting stops past ``limit``)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = v.values()
        elif not isinstance(v, list):
            continue
        deepest = max(deepest, d)
        if d > limit:
            return d
        stack.extend((x, d + 1) for x in v if isinstance(x, (dict, list)))
    return deepest


def parse_json(text: str | bytes, source: str | Path) -> Any:
    """A JSON value, refused (InputError naming ``source``) when it is not UTF-8 JSON or nests
    deeper than :data:`MAX_JSON_DEPTH`; long integers are read as floats (:func:`_int_or_float`)."""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        value = json.loads(text, parse_int=_int_or_float)
    except UnicodeDecodeError as e:
        raise InputError(source, f"not UTF-8 text ({e})") from None
    except json.JSONDecodeError as e:
        raise InputError(source, f"invalid JSON (truncated or corrupt?): {e}") from None
    except RecursionError:
        raise InputError(source, f"JSON nested deeper than {MAX_JSON_DEPTH} levels (MAX_JSON_DEPTH)") from None
    except ValueError as e:
        raise InputError(source, f"invalid JSON: {str(e)[:200]}") from None
    if depth(value) > MAX_JSON_DEPTH:
        raise InputError(source, f"JSON nested deeper than {MAX_JSON_DEPTH} levels (MAX_JSON_DEPTH)")
    return value


def read_json(path: str | Path, max_bytes: int = MAX_JSON_BYTES, limit_name: str = "MAX_JSON_BYTES") -> Any:
    """A JSON file: a regular file of at most ``max_bytes`` (:func:`read_bytes`), parsed by
    :func:`parse_json`."""
    data = read_bytes(path, max_bytes, limit_name)
    if not data:
        raise InputError(path, "file is empty")
    return parse_json(data, path)


# ----------------------------------------------------------------------------- numbers


def finite(value: Any, source: str | Path, where: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a float when it is a number (not a bool, not text), finite and within
    [``low``, ``high``]; else InputError naming ``where``."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    v = float(value) if ok else math.nan
    if not (math.isfinite(v) and low <= v <= high):
        bounds = "" if (low, high) == (-math.inf, math.inf) else f" in [{low:g}, {high:g}]"
        raise InputError(source, f"{where} must be a finite number{bounds}, got {shown(value)}")
    return v


def finite_array(a: np.ndarray, source: str | Path, what: str) -> np.ndarray:
    """``a`` when every value is finite; else InputError naming ``what`` and the first bad index."""
    a = np.asarray(a)
    if a.dtype.kind not in "iuf":
        raise InputError(source, f"{what} must be numbers, not {a.dtype}")
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            first = np.unravel_index(int(np.flatnonzero(bad.ravel())[0]), a.shape)
            raise InputError(
                source, f"{what} holds NaN or inf ({int(bad.sum())} values, first at {tuple(map(int, first))})"
            )
    return a


def count(n: int, bound: int, source: str | Path, what: str, limit_name: str) -> int:
    """``n`` when at most ``bound``; else InputError naming the bound."""
    if n > bound:
        raise InputError(source, f"{n:,} {what}, over the limit of {bound:,} ({limit_name})")
    return n


def local_map(xy: np.ndarray, cls: np.ndarray, source: str | Path, where: str, n_classes: int) -> None:
    """A query's local map read from a table (not through a query file's checks): at most
    :data:`MAX_QUERY_OBJECTS` objects, coordinates finite and within :data:`MAX_LOCAL_COORD`, class
    ids in range."""
    count(len(xy), MAX_QUERY_OBJECTS, source, f"objects in {where}", "MAX_QUERY_OBJECTS")
    if not (np.isfinite(xy).all() and (np.abs(xy) <= MAX_LOCAL_COORD).all()):
        raise InputError(source, f"{where}: x, y must be finite numbers within {MAX_LOCAL_COORD:g} (MAX_LOCAL_COORD)")
    if len(cls) and (cls.min() < 0 or cls.max() >= n_classes):
        raise InputError(source, f"{where}: class_id outside 0..{n_classes - 1}")


# ----------------------------------------------------------------------------- city index


def npz_members(path: str | Path, max_bytes: int = MAX_INDEX_BYTES) -> None:
    """Before ``numpy.load``: ``path`` is a regular file under ``max_bytes`` whose members
    together unpack to at most ``max_bytes`` (a zip bomb is refused before anything is inflated)."""
    import zipfile

    regular_file(path, max_bytes, "MAX_INDEX_BYTES")
    try:
        with zipfile.ZipFile(path) as z:
            total = sum(i.file_size for i in z.infolist())
    except (zipfile.BadZipFile, OSError) as e:
        raise InputError(path, f"not a .npz archive ({e})") from None
    if total > max_bytes:
        raise InputError(
            path, f"its arrays unpack to {total:,} bytes, over the limit of {max_bytes:,} (MAX_INDEX_BYTES)"
        )


def city_index(arrays: dict[str, np.ndarray], path: str | Path, n_classes: int) -> None:
    """A city index's arrays before any kernel sees them: shapes and kinds as :class:`flatlandia.city.index.ViewIndex`
    writes them, every number finite, ``view_ptr`` from 0, non-decreasing, ending at the number of
    seen objects, every seen object and class id in range, ``obj_id`` unique."""
    shapes = {
        "obj_xy": (2, "f"),
        "obj_cls": (1, "iu"),
        "obj_id": (1, "iu"),
        "cam": (2, "f"),
        "view_ptr": (1, "iu"),
        "view_obj": (1, "iu"),
        "idf": (1, "f"),
    }
    for name, (ndim, kinds) in shapes.items():
        a = arrays[name]
        if a.ndim != ndim or a.dtype.kind not in kinds:
            raise InputError(
                path,
                f"{name}: expected a {ndim}-D array of {'floats' if kinds == 'f' else 'integers'}, "
                f"got {a.ndim}-D {a.dtype}",
            )
        finite_array(a, path, name)
    n, views = len(arrays["obj_xy"]), len(arrays["cam"])
    count(n, MAX_INDEX_OBJECTS, path, "objects", "MAX_INDEX_OBJECTS")
    if arrays["obj_xy"].shape[1] != 2 or arrays["cam"].shape[1] != 3:
        raise InputError(path, "obj_xy must be (N, 2) and cam (P, 3)")
    if len(arrays["obj_cls"]) != n or len(arrays["obj_id"]) != n:
        raise InputError(path, f"obj_cls and obj_id must have one entry per object ({n})")
    idf = arrays["idf"]
    if len(idf) < n_classes or (idf < 0).any():
        raise InputError(path, f"idf must hold a weight >= 0 for each of at least {n_classes} classes")
    cls = arrays["obj_cls"]
    if n and (cls.min() < 0 or cls.max() >= len(idf)):
        raise InputError(path, f"obj_cls holds class ids outside 0..{len(idf) - 1}")
    if len(np.unique(arrays["obj_id"])) != n:
        raise InputError(path, "obj_id holds the same object id twice")
    ptr, seen = arrays["view_ptr"], arrays["view_obj"]
    if len(ptr) != views + 1:
        raise InputError(path, f"view_ptr must hold one entry per view and one more ({views + 1}), not {len(ptr)}")
    if ptr[0] != 0 or ptr[-1] != len(seen) or (np.diff(ptr) < 0).any():
        raise InputError(
            path, f"view_ptr must run from 0 to the {len(seen)} seen objects without decreasing (it indexes view_obj)"
        )
    if len(seen) and (seen.min() < 0 or seen.max() >= n):
        raise InputError(path, f"view_obj holds map rows outside 0..{n - 1}")


# ----------------------------------------------------------------------------- maps


def frame_origin(meta: Any, source: str | Path) -> tuple[float, float] | None:
    """A map's metric frame origin (lon0, lat0) from its ``flatlandia`` metadata: None when it
    declares none, else two finite degrees in range; metadata that is not a mapping is refused."""
    if meta is None or meta == {}:
        return None
    if not isinstance(meta, dict):
        raise InputError(source, f"its flatlandia metadata must be a JSON object, not {type(meta).__name__}")
    if meta.get("lon0") is None and meta.get("lat0") is None:
        return None
    lon0 = finite(meta.get("lon0"), source, "metadata lon0", -180.0, 180.0)
    lat0 = finite(meta.get("lat0"), source, "metadata lat0", -90.0, 90.0)
    return lon0, lat0


def frame_matches(lonlat: np.ndarray, xy: np.ndarray, to_xy, origin: tuple[float, float], source: str | Path) -> None:
    """A map whose metadata declares its frame (``origin``, ``to_xy``: lon/lat -> its metres) must
    describe its own data: the origin within :data:`MAX_ORIGIN_OFFSET_M` of its objects and its
    x_m/y_m its lon/lat projected in that frame to :data:`FRAME_TOLERANCE_M` (a forged lon0 moves
    every answer's lon/lat, not its metres)."""
    if not len(lonlat):
        return
    centre = lonlat.mean(axis=0)
    k = 6371008.8 * math.pi / 180
    off = math.hypot((centre[0] - origin[0]) * k * math.cos(math.radians(centre[1])), (centre[1] - origin[1]) * k)
    if not off <= MAX_ORIGIN_OFFSET_M:
        raise InputError(
            source,
            f"its metadata puts the frame's origin (lon0 {origin[0]:g}, lat0 {origin[1]:g}) {off / 1000:,.0f} km from its "
            f"objects (at most {MAX_ORIGIN_OFFSET_M / 1000:g} km): the metadata does not describe this map",
        )
    with np.errstate(all="ignore"):
        proj = np.column_stack(to_xy.transform(lonlat[:, 0], lonlat[:, 1]))
        worst = float(np.max(np.hypot(*(proj - xy).T)))
    if not worst <= FRAME_TOLERANCE_M:
        raise InputError(
            source,
            f"its x_m/y_m are not its lon/lat in the frame its metadata declares (lon0 {origin[0]:g}, lat0 {origin[1]:g}): "
            f"up to {worst:.3g} m apart (at most {FRAME_TOLERANCE_M:g} m)",
        )


def class_counts(cls: np.ndarray, source: str | Path, names: list[str]) -> None:
    """Refuse a scene map with more than :data:`MAX_CLASS_OBJECTS` objects of one class."""
    counts = np.bincount(np.asarray(cls, np.int64), minlength=len(names))
    worst = int(np.argmax(counts)) if len(counts) else 0
    if len(counts) and counts[worst] > MAX_CLASS_OBJECTS:
        raise InputError(
            source,
            f"{int(counts[worst]):,} objects of class {names[worst]!r}, over the limit of {MAX_CLASS_OBJECTS} "
            "(MAX_CLASS_OBJECTS): a map that large is searched through a city index (results/city/{n}/index)",
        )


def unique_ids(ids: np.ndarray, source: str | Path, what: str = "obj_idx") -> None:
    """Refuse an id given to two objects (a match would name either)."""
    values, counts = np.unique(ids, return_counts=True)
    twice = values[counts > 1]
    if len(twice):
        listed = ", ".join(str(int(v)) for v in twice[:5]) + (" ..." if len(twice) > 5 else "")
        raise InputError(source, f"{what} {listed} given to more than one object: each object needs its own {what}")


# ----------------------------------------------------------------------------- learned priors


def map_size_calibration(d: Any, source: str | Path, max_shift: float, max_per_log_odds: float) -> None:
    """A city's map-size correction (rule city_calibration's record,
    :class:`flatlandia.solver.calibration.MapSize` under key ``map_size``): ``reference_objects``
    >= 1; ``frame`` and ``sequence`` each a ``shift`` in [0, ``max_shift``] and a ``per_log_odds``
    in [0, ``max_per_log_odds``]; ``answers`` a count."""
    if not isinstance(d, dict) or not isinstance(d.get("map_size"), dict):
        raise InputError(source, "expected a JSON object with a map_size object (rule city_calibration's record)")
    m = d["map_size"]
    finite(m.get("reference_objects"), source, "map_size reference_objects", 1.0, 1e9)
    for kind in ("frame", "sequence"):
        term = m.get(kind)
        if not isinstance(term, dict):
            raise InputError(
                source, f"map_size {kind} must be an object with shift and per_log_odds, got {shown(term)}"
            )
        finite(term.get("shift"), source, f"map_size {kind} shift", 0.0, max_shift)
        finite(term.get("per_log_odds"), source, f"map_size {kind} per_log_odds", 0.0, max_per_log_odds)
    n = m.get("answers")
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise InputError(source, f"map_size answers must be a count of answers, got {shown(n)}")


def learned_priors(d: Any, source: str | Path, n_features: int) -> None:
    """A solver priors JSON (:class:`flatlandia.solver.learned_priors.LearnedPriors`): ``scale_prior``
    null or (mean, std) finite with std > 0; ``verifier`` null or ``weights``, ``mean``,
    ``scale`` of ``n_features`` finite numbers each, every scale > 0."""
    if not isinstance(d, dict):
        raise InputError(source, "expected a JSON object with scale_prior and verifier")
    sp = d.get("scale_prior")
    if sp:
        if not isinstance(sp, list) or len(sp) != 2:
            raise InputError(source, f"scale_prior must be [mean, std] of log metres per unit, got {shown(sp)}")
        finite(sp[0], source, "scale_prior mean", -50.0, 50.0)
        std = finite(sp[1], source, "scale_prior std", 0.0, 50.0)
        if std <= 0:
            raise InputError(source, f"scale_prior std must be > 0, got {shown(sp[1])}")
    v = d.get("verifier")
    if v:
        if not isinstance(v, dict):
            raise InputError(source, "verifier must be an object with weights, mean and scale")
        for key in ("weights", "mean", "scale"):
            values = v.get(key)
            if not isinstance(values, list) or len(values) != n_features:
                raise InputError(
                    source, f"verifier {key} must list {n_features} numbers (one per feature), got {shown(values)}"
                )
            for i, x in enumerate(values):
                finite(x, source, f"verifier {key}[{i}]")
                if key == "scale" and x <= 0:
                    raise InputError(source, f"verifier scale[{i}] must be > 0, got {shown(x)}")
