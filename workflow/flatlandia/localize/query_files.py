"""A user's queries and sequences as JSON: read and checked at the door (:func:`parse_query`,
:func:`read_queries`, :func:`parse_sequence`, :func:`read_sequence`) and written (:func:`query_json`);
a photo made into a query by the configured backends (:func:`read_photo`).

Bad input raises :class:`~flatlandia.plumbing.errors.InputError`, one line naming the file and the
problem (an unknown class with the closest label, fewer than 3 objects, a coordinate that is not a
finite number).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError
from flatlandia.sequences import MIN_SIGMA_DEG, MIN_SIGMA_M

#: fewest objects a query needs (a 2-point fit and one object to check it)
MIN_OBJECTS = geo.MIN_OBJECTS


def class_id(label: Any, source: str | Path, where: str) -> int:
    """The class id of a Vistas label (``classes.tsv``); unknown: InputError naming the closest."""
    if isinstance(label, str) and label in _CLASS_IDS:
        return _CLASS_IDS[label]
    short = len(str(label)) <= 2 * max(map(len, CLASSES))  # a long text is like no label: no search
    closest = difflib.get_close_matches(str(label), CLASSES, n=1, cutoff=0.0) if short else []
    hint = f"; closest known label: {closest[0]!r}" if closest else ""
    raise InputError(
        source, f"{where}: unknown class {validate.shown(label)}{hint} (the Mapillary Vistas labels of classes.tsv)"
    )


_CLASS_IDS = {c: k for k, c in enumerate(CLASSES)}


def class_ids(values, source, what: str, ids: bool) -> np.ndarray:
    """Class ids of a map's objects from labels (or, ``ids``, integer ids in range)."""
    out = np.empty(len(values), np.int64)
    for k, v in enumerate(values):
        if ids:
            try:
                c = int(v)
            except (TypeError, ValueError):
                raise InputError(source, f"{what} {k}: class_id {validate.shown(v)} is not an integer") from None
            if not 0 <= c < len(CLASSES) or c != v:
                raise InputError(
                    source, f"{what} {k}: class_id {validate.shown(v)} is not one of 0..{len(CLASSES) - 1}"
                )
            out[k] = c
        else:
            out[k] = class_id(v, source, f"{what} {k}")
    return out


@dataclass
class Query:
    """One query: its local map (M, 2), x forward, y left, and the class ids of its objects."""

    id: str | None
    xy: np.ndarray
    cls: np.ndarray
    source: str = "<query>"

    @property
    def labels(self) -> list[str]:
        return [CLASSES[c] for c in self.cls]


def parse_query(obj: Any, source: str | Path = "<query>", qid: str | None = None) -> Query:
    """A query from its JSON value ``{"objects": [{"class", "x", "y"}, ...]}``; InputError naming
    the ``source`` and what is wrong (an unknown class with the closest label, fewer than 3
    objects, a coordinate that is not a finite number)."""
    name = f"query {validate.shown(qid)}" if qid is not None else "query"
    if not isinstance(obj, dict) or not isinstance(obj.get("objects"), list):
        raise InputError(source, f'{name}: expected {{"objects": [{{"class": ..., "x": ..., "y": ...}}, ...]}}')
    qid = str(obj["id"]) if obj.get("id") is not None else qid
    name = f"query {validate.shown(qid)}" if qid is not None else "query"
    objects = obj["objects"]
    if len(objects) < MIN_OBJECTS:
        raise InputError(source, f"{name} has {len(objects)} objects; at least {MIN_OBJECTS} are needed")
    validate.count(len(objects), validate.MAX_QUERY_OBJECTS, source, f"objects in {name}", "MAX_QUERY_OBJECTS")
    xy, cls = np.empty((len(objects), 2)), np.empty(len(objects), np.int64)
    for k, o in enumerate(objects):
        where = f"{name} object {k}"
        if not isinstance(o, dict) or "class" not in o:
            raise InputError(source, f'{where}: expected {{"class": "<Vistas label>", "x": ..., "y": ...}}')
        cls[k] = class_id(o["class"], source, where)
        for j, axis in enumerate("xy"):
            v = o.get(axis)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(
                    source, f"{where}: {axis} must be a finite number of the local map, got {validate.shown(v)}"
                )
            xy[k, j] = validate.finite(
                v, source, f"{where}: {axis} (MAX_LOCAL_COORD)", -validate.MAX_LOCAL_COORD, validate.MAX_LOCAL_COORD
            )
    if np.any(np.hypot(xy[:, 0], xy[:, 1]) == 0):
        raise InputError(source, f"{name}: an object at the camera (0, 0) has no bearing")
    return Query(qid, xy, cls, str(source))


def read_queries(path: str | Path) -> tuple[list[Query], bool]:
    """The queries of a JSON file and whether it held many (``{"queries": [...]}``) or one."""
    doc = validate.read_json(path, validate.MAX_QUERY_JSON_BYTES, "MAX_QUERY_JSON_BYTES")
    if isinstance(doc, dict) and "queries" in doc:
        if not isinstance(doc["queries"], list) or not doc["queries"]:
            raise InputError(path, '"queries" must be a non-empty list of {"id": ..., "objects": [...]}')
        validate.count(len(doc["queries"]), validate.MAX_QUERIES, path, "queries", "MAX_QUERIES")
        return [parse_query(q, path, str(k)) for k, q in enumerate(doc["queries"])], True
    return [parse_query(doc, path)], False


def query_json(xy, classes, qid: str | None = None) -> dict:
    """The JSON value of a query (a local map and its class ids or labels): what
    :func:`parse_query` reads; floats written as Python's repr, so the file holds them exactly."""
    labels = [CLASSES[int(c)] if not isinstance(c, str) else c for c in classes]
    out = {"objects": [{"class": c, "x": float(p[0]), "y": float(p[1])} for c, p in zip(labels, np.asarray(xy, float))]}
    return {"id": qid, **out} if qid is not None else out


@dataclass
class Sequence:
    """Frames localized together: the anchor first; each frame's pose in the anchor's camera frame
    (dx forward, dy left in metres, dtheta in radians; row 0 zeros) and its noise (metres, radians)."""

    frames: list[Query]
    rel: np.ndarray  # (F, 3)
    sigma: np.ndarray  # (F, 2)
    source: str = "<sequence>"


def _number(v, source, where: str, positive: bool = False, bound: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        kind = "a positive number" if positive else "a finite number"
        raise InputError(source, f"{where} must be {kind}, got {validate.shown(v)}")
    if abs(v) > bound:
        raise InputError(source, f"{where} must be at most {bound:g} in size, got {validate.shown(v)}")
    return float(v)


def parse_sequence(obj: Any, source: str | Path = "<sequence>") -> Sequence:
    """A sequence from its JSON value (module docstring): ``{"frames": [{"objects": [...]}, {"objects":
    [...], "pose": {"x", "y", "theta_deg"}, "sigma_m", "sigma_deg"}, ...]}``. A companion's pose is
    required; its noise defaults to the benchmark's odometry model (``beyond.odometry_distance_pct``
    of its distance, ``beyond.odometry_heading_deg`` per frame along the sequence)."""
    from flatlandia import config

    if not isinstance(obj, dict) or not isinstance(obj.get("frames"), list) or not obj["frames"]:
        raise InputError(
            source,
            'expected {"frames": [{"objects": [...]}, {"objects": [...], "pose": {"x": ..., "y": ..., "theta_deg": ...}}, ...]}',
        )
    validate.count(len(obj["frames"]), validate.MAX_SEQUENCE_FRAMES, source, "frames", "MAX_SEQUENCE_FRAMES")
    beyond = config.section_defaults("beyond")
    frames, rel, sigma = [], [], []
    for k, f in enumerate(obj["frames"]):
        where = f"frame {k}"
        if not isinstance(f, dict):
            raise InputError(source, f"{where}: expected an object with its objects (and, after the first, its pose)")
        frames.append(parse_query(f, source, str(f.get("id", k))))
        if k == 0:
            rel.append((0.0, 0.0, 0.0))
            sigma.append((0.0, 0.0))
            continue
        pose = f.get("pose")
        if not isinstance(pose, dict):
            raise InputError(
                source,
                f'{where}: needs "pose": {{"x": forward m, "y": left m, "theta_deg": turn}} in the first frame\'s camera frame',
            )
        x, y = (_number(pose.get(a), source, f"{where} pose {a}", bound=validate.MAX_ODOMETRY_M) for a in ("x", "y"))
        th = _number(pose.get("theta_deg", 0.0), source, f"{where} pose theta_deg", bound=360.0)
        rel.append((x, y, math.radians(th)))
        sm = f.get("sigma_m", max(MIN_SIGMA_M, beyond["odometry_distance_pct"] / 100 * math.hypot(x, y)))
        sd = f.get("sigma_deg", max(MIN_SIGMA_DEG, beyond["odometry_heading_deg"] * math.sqrt(k)))
        sigma.append(
            (
                _number(sm, source, f"{where} sigma_m", True, validate.MAX_ODOMETRY_M),
                math.radians(_number(sd, source, f"{where} sigma_deg", True, validate.MAX_COMPASS_SIGMA_DEG)),
            )
        )
    return Sequence(frames, np.array(rel, float), np.array(sigma, float), str(source))


def read_sequence(path: str | Path) -> Sequence:
    """The sequence of a JSON file (:func:`parse_sequence`)."""
    return parse_sequence(validate.read_json(path, validate.MAX_QUERY_JSON_BYTES, "MAX_QUERY_JSON_BYTES"), path)


def read_photo(path: str | Path, settings: dict | None = None) -> tuple[Query, dict]:
    """(the depth query of one photo, the record of how it was made: the answer's ``photo``), by
    :func:`flatlandia.images.photo_query.photo_query` under ``settings`` (the config or any of its
    sections; None: the schema's defaults), then through :func:`parse_query`'s door as any query."""
    try:
        from flatlandia.images import photo_query  # pillow, torch and the backends: only for a photo

        made = photo_query.photo_query(path, settings)
    except ImportError as e:  # the localizer installed alone (docs/usage.md)
        raise InputError(
            path,
            f"a photo's query needs {e.name or e} (pillow, torch, transformers and kornia: the extra workflow, "
            "pip install 'flatlandia[workflow]')",
        ) from None
    return parse_query(query_json(made.xy, made.cls, made.name), path), made.record()
