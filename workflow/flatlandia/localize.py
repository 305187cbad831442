"""Localize your own query: the camera pose of one image's objects on a reference map.

The Python side of ``flatlandia localize`` (workflow/flatlandia/cli.py), on the benchmark's code
path: the pose is :func:`flatlandia.solver.localize`'s, the function rule fine_eval and the city
search call, so a published test query written as a query file comes back with the pose the
benchmark's whole-map run gives it.

A **map** is loaded once (:func:`load_map`) and answers many queries (:func:`localize`):

- a scene's reference map: the workflow's ``results/{scene}/maps/reference_map.parquet`` (or its
  ``.geojson``), or any GeoParquet / GeoJSON of classed points (a ``class_label``, ``class`` or
  ``label`` property holding a Mapillary Vistas label of ``classes.tsv``, or a ``class_id``; lon/lat
  as columns, Point geometries or, for GeoJSON, coordinates). The workflow's maps come with what
  the benchmark gives the solver when the files exist: the scene's training cameras (the train
  split of ``results/{scene}/queries/queries.parquet``: the camera prior and co-visibility) and,
  for depth queries, the learned scale prior and verifier (``results/solver/priors/whole.json``);
  any other map is searched without priors unless ``learned`` names a priors file;
- a city index (``results/city/{n}/index``, or one of its ``.npz``): the city search
  (:mod:`flatlandia.city.search`: the index proposes regions, the solver searches them with the
  training views there as priors); lon/lat come from the city's ``map.parquet`` beside the index
  (a tiled city: each tile is a published scene moved by a translation, and keeps its lon/lat).

A **query** is JSON, ``{"objects": [{"class": "<Vistas label>", "x": <forward>, "y": <left>}, ...]}``
(camera at the origin looking along +x, +y to its left; at least 3 objects), or a file of many,
``{"queries": [{"id": ..., "objects": [...]}, ...]}``. Map type ``gt``: x/y in metres; ``depth``: x/y
in any unit (the scale is unknown and solved for; bearings must be true).

A **prior** (optional): a phone's GPS fix ``gps=(lon, lat, sigma_m)`` and a compass heading
``compass=(heading_deg clockwise from north, sigma_deg)``, weighed as Gaussian likelihoods by the
solver (poses within 4 sigma of the fix are kept; on a city the fix's region replaces the index's).
A **sequence** (optional, depth maps): several frames localized together (:func:`read_sequence`,
:func:`localize_sequence`), ``{"frames": [{"objects": [...]}, {"objects": [...], "pose": {"x":
<forward m>, "y": <left m>, "theta_deg": <turn, counter-clockwise>}, "sigma_m": ..., "sigma_deg":
...}, ...]}``: the first frame is the anchor, whose pose is returned; each other frame gives where its
camera stood in the anchor's camera frame (odometry) and, optionally, that pose's noise.

Each answer is a dict (:func:`localize`): the pose (lon, lat, x_m, y_m in the map's metric frame,
heading_deg clockwise from north, theta_deg counter-clockwise from east as the benchmark's tables),
the depth map's scale, a confidence, which map object each query object matched, the next-best
distinct poses and the priors used, and the answer's ``status`` (``ok``, ``ambiguous`` or ``no pose``)
with its calibrated ``probability`` of being within (5 m, 5 deg) (each alternative has its own). Bad input raises :class:`flatlandia.errors.InputError`, one
line naming the file and the problem.
"""

from __future__ import annotations

import difflib
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flatlandia import geo, paths, validate, vocabulary
from flatlandia.beyond import MIN_SIGMA_DEG, MIN_SIGMA_M
from flatlandia.classes import CLASSES
from flatlandia.errors import InputError

# the solver loads numba (seconds; docs/measurements.md, "Start-up costs"): only a loaded map needs it
if TYPE_CHECKING:
    import pandas as pd

    from flatlandia import solver
    from flatlandia.city.index import ViewIndex
    from flatlandia.city.search import SearchConfig

MAP_TYPES = vocabulary.MAP_TYPES
#: fewest objects a query needs (a 2-point fit and one object to check it)
MIN_OBJECTS = geo.MIN_OBJECTS
#: next-best distinct poses returned by default (also `flatlandia localize --alternatives`'s default)
ALTERNATIVES = 3
#: a depth query whose median object range is within this of 1 is used as given: the benchmark's
#: depth maps are normalised so (the scale prior is in metres per such unit); any other is scaled
NORMALISED_TOL = 1e-4
#: class properties of a map, in the order they are looked for (labels before ids)
LABEL_KEYS = ("class_label", "class", "label")
ID_KEY = "class_id"
#: lon/lat column names of a map table
LON_KEYS, LAT_KEYS = ("lon", "longitude", "lng"), ("lat", "latitude")


# ----------------------------------------------------------------------------- classes


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


def _class_ids(values, source, what: str, ids: bool) -> np.ndarray:
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


# ----------------------------------------------------------------------------- queries


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


# ----------------------------------------------------------------------------- maps


@dataclass
class Tile:
    """Where a scene's tile of a tiled city lies: its metric frame and the translation into the city."""

    scene: str
    to_lonlat: Any  # Transformer, tile metres -> lon/lat
    to_xy: Any  # Transformer, lon/lat -> tile metres
    offset: np.ndarray  # (2,) city = tile + offset


@dataclass
class ObjectMap:
    """A loaded map: the objects (map rows), its frame, the solver's priors and, for a city, the index."""

    path: Path
    kind: str  # "scene" or "city"
    obj_idx: np.ndarray  # (N,) the map's object ids
    cls: np.ndarray  # (N,) class ids
    xy: np.ndarray  # (N, 2) metres of the map's frame
    lonlat: np.ndarray | None  # (N, 2) degrees, None without a geographic frame
    settings: solver.SolverConfig
    frame: str  # what the metric frame is, in words
    to_lonlat: Any = None  # Transformer metres -> lon/lat of a scene map (None: no geographic frame)
    to_xy: Any = None  # and back
    scene: str | None = None
    queries_path: Path | None = None  # where the training cameras came from
    cameras: int = 0  # training cameras among the priors
    learned: solver.LearnedPriors | None = None
    learned_path: Path | None = None
    map_size_path: Path | None = None  # city: the map-size correction of the probability (rule city_calibration)
    priors: dict = field(default_factory=dict)  # map type -> solver.TrainingPriors over the rows
    index: ViewIndex | None = None
    search: SearchConfig | None = None
    tiles: dict = field(default_factory=dict)  # city: scene -> Tile (lazily)
    obj_scene: np.ndarray | None = None  # city: scene of each row
    obj_scene_idx: np.ndarray | None = None  # city: each row's obj_idx in its scene
    cities: dict = field(default_factory=dict)  # scene -> its city's name, where the results folder says

    def priors_used(self, map_type: str) -> dict:
        """What the solver knew beyond the query and the map, for one map type."""
        depth = map_type == "depth"
        lp = self.learned if depth else None
        return {
            "training_cameras": int(self.cameras),
            "cameras_from": str(self.queries_path) if self.queries_path and self.cameras else None,
            "learned_from": str(self.learned_path) if lp is not None and self.learned_path else None,
            "scale_prior": bool(lp is not None and lp.scale is not None),
            "verifier": bool(lp is not None and lp.verifier is not None and self.cameras > 0),
            **(
                {"map_size_from": str(self.map_size_path) if lp is not None and self.map_size_path else None}
                if self.kind == "city"
                else {}
            ),
        }


def _workflow_paths(path: Path) -> tuple[Path | None, str | None, Path | None, Path | None]:
    """(results folder, scene, queries, learned priors) of a workflow map ``results/{scene}/maps/
    reference_map.*`` (paths.reference_map; None each where the path is not one or the file is missing)."""
    found = paths.locate(path, paths.reference_map, ext=path.suffix[1:])
    if found is None:
        return None, None, None, None
    results, scene = found[0], found[1]["scene"]
    queries = paths.within(results, paths.queries(scene))
    learned = paths.within(results, paths.solver_priors(vocabulary.WHOLE))
    return results, scene, queries if queries.is_file() else None, learned if learned.is_file() else None


def _transformers(lon0: float, lat0: float):
    """(metres -> lon/lat, lon/lat -> metres) of a scene frame (:class:`flatlandia.geo.MetricFrame`),
    built once: a transformer costs far more than a query's few points (docs/measurements.md, "Start-up costs")."""
    from pyproj import CRS, Transformer

    from flatlandia import geo

    frame = geo.MetricFrame(lon0, lat0)
    crs = CRS.from_proj4(frame.proj4)
    wgs = CRS.from_epsg(4326)
    return Transformer.from_crs(crs, wgs, always_xy=True), Transformer.from_crs(wgs, crs, always_xy=True)


def _pick(columns, keys) -> str | None:
    low = {str(c).lower(): c for c in columns}
    return next((low[k] for k in keys if k in low), None)


def _table_classes(df: pd.DataFrame, path: Path) -> np.ndarray:
    key = _pick(df.columns, LABEL_KEYS)
    if key is not None:
        return _class_ids(df[key].tolist(), path, "object", ids=False)
    if ID_KEY in df.columns:
        return _class_ids(df[ID_KEY].tolist(), path, "object", ids=True)
    raise InputError(path, f"no class property: expected one of {', '.join(LABEL_KEYS + (ID_KEY,))}")


def _read_table(path: Path) -> tuple[pd.DataFrame, dict]:
    """A map table from Parquet (its ``flatlandia`` metadata: the workflow's frame) or GeoJSON."""
    import pandas as pd

    from flatlandia import io

    if path.suffix.lower() == ".parquet":
        try:
            validate.parquet_size(
                path, validate.MAX_MAP_OBJECTS, validate.MAX_MAP_BYTES, "objects", ("MAX_MAP_OBJECTS", "MAX_MAP_BYTES")
            )
            df = pd.read_parquet(path)
            meta = io.read_parquet_metadata(path)
        except InputError:
            raise
        except Exception as e:  # pyarrow raises several types for files that are not Parquet
            raise InputError(path, f"not a readable Parquet file ({type(e).__name__}: {e})") from None
        if "geometry" in df.columns and not (_pick(df.columns, LON_KEYS) and _pick(df.columns, LAT_KEYS)):
            df = _geometry_lonlat(path, df)
        return df, meta
    doc = validate.read_json(path, validate.MAX_MAP_BYTES, "MAX_MAP_BYTES")
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list):
        raise InputError(path, "not GeoJSON: expected a FeatureCollection with a list of features")
    validate.count(len(feats), validate.MAX_MAP_OBJECTS, path, "features", "MAX_MAP_OBJECTS")
    meta = doc.get("flatlandia") if isinstance(doc.get("flatlandia"), dict) else {}
    rows = []
    for k, f in enumerate(feats):
        geom = f.get("geometry") if isinstance(f, dict) else None
        coords = geom.get("coordinates") if isinstance(geom, dict) else None
        if not isinstance(geom, dict) or geom.get("type") != "Point" or not isinstance(coords, list) or len(coords) < 2:
            raise InputError(path, f"feature {k}: expected a Point geometry with [lon, lat] coordinates")
        if any(isinstance(c, bool) for c in coords[:2]):
            raise InputError(path, f"feature {k}: coordinates must be numbers, not true/false")
        props = f.get("properties")
        if props is not None and not isinstance(props, dict):
            raise InputError(
                path, f"feature {k}: properties must be a JSON object (or null), not {type(props).__name__}"
            )
        rows.append({**(props or {}), "lon": coords[0], "lat": coords[1]})
    df = pd.DataFrame(rows)
    if meta.get("frame") == "local":  # a map without GPS: its coordinates are x/y, not lon/lat
        df = df.drop(columns=["lon", "lat"])
    return df, meta


def _geometry_lonlat(path: Path, df: pd.DataFrame) -> pd.DataFrame:
    """lon/lat columns of a GeoParquet without them, from its point geometries (in EPSG:4326)."""
    try:
        import geopandas as gpd

        g = gpd.read_parquet(path)
        if g.crs is not None and not g.crs.equals("EPSG:4326") and not g.crs.equals("OGC:CRS84"):
            g = g.to_crs("EPSG:4326")
        if not (g.geometry.geom_type == "Point").all():
            raise InputError(path, "the geometries must be points (one per object)")
        return df.assign(lon=g.geometry.x.to_numpy(), lat=g.geometry.y.to_numpy())
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"could not read its point geometries ({type(e).__name__}: {e})") from None


def _numbers(df: pd.DataFrame, columns: list[str], path: Path, dtype=float) -> np.ndarray:
    """(N, len(columns)) numbers of a map's columns; InputError naming the column otherwise."""
    out = np.empty((len(df), len(columns)), dtype)
    for j, c in enumerate(columns):
        try:
            v = df[c].to_numpy(float)
        except (TypeError, ValueError) as e:
            raise InputError(path, f"{c}: not numbers ({e})") from None
        if dtype is not float and not (np.isfinite(v).all() and (v == np.round(v)).all()):
            raise InputError(path, f"{c}: not integers")
        out[:, j] = v
    return out


def _scene_map(path: Path, settings, learned) -> ObjectMap:
    """A scene's reference map (the workflow's, or any table of classed points)."""
    from flatlandia import solver

    df, meta = _read_table(path)
    if len(df) == 0:
        raise InputError(path, "the map holds no objects")
    origin = validate.frame_origin(meta, path)  # metadata that is no object, or a lon0 that is no degree: refused
    meta = meta or {}
    cls = _table_classes(df, path)
    validate.class_counts(cls, path, CLASSES)  # the solver's candidates grow with the objects of a class
    obj = _numbers(df, ["obj_idx"], path, np.int64)[:, 0] if "obj_idx" in df.columns else np.arange(len(df))
    validate.unique_ids(obj, path)
    lon, lat = _pick(df.columns, LON_KEYS), _pick(df.columns, LAT_KEYS)
    lonlat = _numbers(df, [lon, lat], path) if lon and lat else None
    ours = origin is not None and {"x_m", "y_m"} <= set(df.columns)
    to_lonlat = to_xy = None
    if meta.get("frame") == "local" and {"x_m", "y_m"} <= set(df.columns):  # an images scene without GPS
        xy, lonlat, frame = (
            _numbers(df, ["x_m", "y_m"], path),
            None,
            f"local ({meta.get('unit', 'SfM unit')}), no lon/lat",
        )
    elif lonlat is None:
        raise InputError(path, "no lon/lat: expected lon and lat columns or properties, or point geometries")
    else:
        if not np.isfinite(lonlat).all() or (np.abs(lonlat[:, 0]) > 180).any() or (np.abs(lonlat[:, 1]) > 90).any():
            raise InputError(path, "lon/lat must be finite degrees (lon in [-180, 180], lat in [-90, 90])")
        if ours:  # the workflow's map: its own frame and metres, as the benchmark reads them
            lon0, lat0 = origin
            xy = _numbers(df, ["x_m", "y_m"], path)
        else:
            from flatlandia import geo

            f = geo.frame_for(lonlat)
            lon0, lat0 = f.lon0, f.lat0
        to_lonlat, to_xy = _transformers(lon0, lat0)
        if not ours:
            xy = np.column_stack(to_xy.transform(lonlat[:, 0], lonlat[:, 1]))
        elif np.isfinite(xy).all():  # the metadata must describe the map's own lon/lat and metres
            validate.frame_matches(lonlat, xy, to_xy, origin, path)
        frame = f"transverse Mercator at lon {lon0:.7f}, lat {lat0:.7f} (x east, y north, metres)"
    if not np.isfinite(xy).all():
        raise InputError(path, "some objects have no finite position")
    results, scene, queries_path, learned_auto = _workflow_paths(path)
    settings = solver.SolverConfig.of(settings)
    m = ObjectMap(path, "scene", obj, cls, xy, lonlat, settings, frame, to_lonlat, to_xy, scene=scene)
    m.learned_path = learned_auto if learned == "auto" else (Path(learned) if learned else None)
    m.learned = solver.LearnedPriors.read(m.learned_path) if m.learned_path else None
    training = None
    if queries_path is not None:
        import pandas as pd

        try:
            training = pd.read_parquet(queries_path)
        except Exception as e:
            raise InputError(queries_path, f"not a readable Parquet file ({type(e).__name__}: {e})") from None
    set_training_priors(m, training, queries_path)
    if scene is not None:
        m.cities = scene_cities(results)
    return m


def scene_cities(results: Path) -> dict:
    """scene -> its city's name, from a results folder's ``tables/dataset_stats_per_scene.parquet``
    (rule dataset_stats; empty where it is missing or unreadable: the answers then give no city)."""
    import pandas as pd

    table = paths.within(results, paths.BENCHMARK_RECORD)
    try:
        t = pd.read_parquet(table, columns=["scene", "city"])
    except Exception:  # missing, or not the table: a city name is a courtesy, not needed for a pose
        return {}
    return dict(zip(t["scene"].astype(str), t["city"].astype(str)))


def set_training_priors(m: ObjectMap, training: pd.DataFrame | None, source: Path | None = None) -> None:
    """A scene map's priors per map type, as rule fine_eval gives them: the cameras of ``training``'s
    train split and what they saw (columns ``split``, ``x_m``, ``y_m``, ``theta_deg``, ``ref_idx``:
    the workflow's queries.parquet, or an export's ground_truth.csv read so), for depth maps with
    the map's learned priors; None: the learned scale prior alone. ``source``: where they came from."""
    from flatlandia import solver

    ref = pd_frame(m.obj_idx)
    for map_type in MAP_TYPES:  # as rule fine_eval: cameras and co-visibility; depth maps the learned priors
        lp = m.learned if map_type == "depth" else None
        if training is not None:
            m.priors[map_type] = solver.scene_priors(ref, training, m.settings, lp)
        else:
            m.priors[map_type] = solver.TrainingPriors().with_learned(lp) if lp is not None else None
    cams = m.priors["gt"].cameras if m.priors["gt"] is not None else None
    m.cameras = 0 if cams is None else len(cams)
    m.queries_path = source if training is not None else None


def pd_frame(obj_idx) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame({"obj_idx": np.asarray(obj_idx, np.int64)})


def _city_map(path: Path, settings, learned, search) -> ObjectMap:
    """A city index (one ``.npz`` of ``results/city/{n}/index``) and, beside it, its map's lon/lat."""
    from flatlandia import solver
    from flatlandia.city import search as city_search
    from flatlandia.city.index import ViewIndex

    try:
        ix = ViewIndex.load(path)  # checked there (flatlandia.validate.city_index)
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"not a city index ({type(e).__name__}: {e})") from None
    if ix.n_objects == 0:
        raise InputError(path, "the map holds no objects")
    settings = solver.SolverConfig.of(settings)
    frame = "the city's tiled frame (metres; each tile a scene's frame moved by a translation)"
    m = ObjectMap(path, "city", ix.obj_id, ix.obj_cls, ix.obj_xy, None, settings, frame, index=ix)
    m.search = search if isinstance(search, city_search.SearchConfig) else city_search.SearchConfig.from_dict(search)
    m.cameras = len(ix.cam)
    m.queries_path = path
    city_dir = path.parent.parent
    auto = paths.within(city_dir.parent.parent, paths.solver_priors(vocabulary.WHOLE))
    m.learned_path = (auto if auto.is_file() else None) if learned == "auto" else (Path(learned) if learned else None)
    m.learned = solver.LearnedPriors.read(m.learned_path) if m.learned_path else None
    correction = paths.within(city_dir.parent.parent, paths.city_calibration())  # rule city_calibration
    if m.learned is not None and path.parent.name == "index" and correction.is_file():
        from flatlandia.solver.learned import read_map_size

        m.learned, m.map_size_path = m.learned.with_map_size(read_map_size(correction)), correction
    table = city_dir / "map.parquet"
    if path.parent.name == "index" and table.is_file():
        import pandas as pd

        try:
            validate.parquet_size(
                table,
                validate.MAX_INDEX_OBJECTS,
                validate.MAX_INDEX_BYTES,
                "objects",
                ("MAX_INDEX_OBJECTS", "MAX_INDEX_BYTES"),
            )
            t = pd.read_parquet(table, columns=["city", "scene", "obj_idx", "scene_obj_idx", "lon", "lat"])
        except InputError:
            raise
        except Exception as e:
            raise InputError(table, f"not the city's map ({type(e).__name__}: {e})") from None
        t = t[t["city"].astype(str) == path.stem].set_index("obj_idx")
        if set(t.index) >= set(ix.obj_id.tolist()):
            t = t.loc[ix.obj_id]
            m.lonlat = validate.finite_array(t[["lon", "lat"]].to_numpy(float), table, "lon/lat")
            if (np.abs(m.lonlat[:, 0]) > 180).any() or (np.abs(m.lonlat[:, 1]) > 90).any():
                raise InputError(table, "lon/lat must be degrees (lon in [-180, 180], lat in [-90, 90])")
            m.obj_scene = t["scene"].astype(str).to_numpy()
            m.obj_scene_idx = t["scene_obj_idx"].to_numpy(np.int64)
    m.cities = scene_cities(city_dir.parent.parent)
    return m


def load_map(
    path: str | Path,
    settings: solver.SolverConfig | dict | None = None,
    learned: str | Path | None = "auto",
    search: SearchConfig | dict | None = None,
) -> ObjectMap:
    """A map, loaded once for many queries: a scene's reference map (``.parquet``, ``.geojson``) or
    a city index (``.npz``, or an index folder holding one). ``settings``: the solver's (config
    section ``solver``; None: the schema's defaults, the workflow's default run); ``learned``: the
    depth maps' learned priors, ``"auto"`` the workflow's ``results/solver/priors/whole.json`` for a
    workflow map, a path, or None for none; ``search``: a city's search settings (``city.search``).
    Also loads the solver's compiled kernels, so that query times exclude that."""
    from flatlandia import solver

    path = Path(path)
    if not path.exists():
        raise InputError(path, "file is missing")
    if path.is_dir():
        found = sorted(path.glob("*.npz"))
        if len(found) != 1:
            listed = ", ".join(p.name for p in found[:8]) or "none"
            raise InputError(path, f"a city index folder holds one .npz per city ({listed}): name one")
        path = found[0]
    validate.regular_file(path)  # a pipe or a device is refused without being opened
    suffix = path.suffix.lower()
    if suffix == ".npz":
        m = _city_map(path, settings, learned, search)
    elif suffix in (".parquet", ".geojson", ".json"):
        if path.stat().st_size == 0:
            raise InputError(path, "file is empty")
        m = _scene_map(path, settings, learned)
    else:
        raise InputError(
            path, "not a map: expected a reference map (.parquet, .geojson) or a city index (.npz, folder)"
        )
    solver.warm_up()
    return m


# ----------------------------------------------------------------------------- answers


def _lonlat_of(m: ObjectMap, xy: np.ndarray) -> tuple[float | None, float | None]:
    if m.kind == "city":
        tile = _tile_at(m, xy)
        if tile is None:
            return None, None
        lon, lat = tile.to_lonlat.transform(float(xy[0] - tile.offset[0]), float(xy[1] - tile.offset[1]))
    elif m.to_lonlat is not None:
        lon, lat = m.to_lonlat.transform(float(xy[0]), float(xy[1]))
    else:
        return None, None
    return float(lon), float(lat)


def _tile_at(m: ObjectMap, xy) -> Tile | None:
    """The tile of the city object nearest ``xy`` (None without the city's lon/lat)."""
    if m.obj_scene is None:
        return None
    _, row = m.index.obj_tree.query(np.asarray(xy, float))
    return _tile(m, str(m.obj_scene[int(row)]))


def _tile(m: ObjectMap, scene: str) -> Tile | None:
    """A city tile's frame (its scene's, :func:`flatlandia.geo.frame_for` of its objects, as the
    published scenes') and translation, from its objects' lon/lat and city metres; None when no
    translation fits them (to 1 cm)."""
    if scene not in m.tiles:
        from flatlandia import geo

        rows = m.obj_scene == scene
        f = geo.frame_for(m.lonlat[rows])
        to_lonlat, to_xy = _transformers(f.lon0, f.lat0)
        local = np.column_stack(to_xy.transform(m.lonlat[rows, 0], m.lonlat[rows, 1]))
        offset = np.mean(m.xy[rows] - local, axis=0)
        fits = np.abs(m.xy[rows] - local - offset).max() < 0.01
        m.tiles[scene] = Tile(scene, to_lonlat, to_xy, offset) if fits else None
    return m.tiles[scene]


def _near_rows(m: ObjectMap, near: tuple[float, float], radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(map rows within ``radius_m`` of lon/lat ``near``, (K, 2) the prior's position in the map's
    metres: one per city tile that has such objects)."""
    lon, lat = float(near[0]), float(near[1])
    if m.kind == "scene":
        if m.to_xy is None:
            raise InputError(m.path, "--near needs a map with lon/lat; this one has a local frame")
        c = np.array(m.to_xy.transform(lon, lat), float)
        return np.flatnonzero(np.hypot(*(m.xy - c).T) <= radius_m), c[None]
    if m.obj_scene is None:
        raise InputError(m.path, "--near needs the city's lon/lat (its map.parquet beside the index folder)")
    # each tile keeps its scene's lon/lat: a prior position falls in the tiles whose objects are near it
    k = 6371008.8 * math.pi / 180
    d = np.hypot((m.lonlat[:, 0] - lon) * k * math.cos(math.radians(lat)), (m.lonlat[:, 1] - lat) * k)
    centres = []
    for scene in sorted(set(m.obj_scene[d <= radius_m + 1.0].tolist())):
        tile = _tile(m, scene)
        if tile is not None:
            centres.append(np.array(tile.to_xy.transform(lon, lat), float) + tile.offset)
    centres = np.array(centres).reshape(-1, 2)
    rows = np.unique(np.concatenate([m.index.obj_tree.query_ball_point(c, radius_m) for c in centres] + [[]]))
    return rows.astype(np.int64), centres


def _pose(m: ObjectMap, sol, unit: float, rows: np.ndarray, q: Query) -> dict:
    """A solution's pose and matches as JSON values (``rows``: the map rows it searched)."""
    theta = math.degrees(math.atan2(math.sin(sol.theta), math.cos(sol.theta)))
    lon, lat = _lonlat_of(m, np.array([sol.x, sol.y]))
    matches = []
    for k, c in sol.inliers:
        row = int(rows[c])
        match = {
            "query_object": int(k),
            "obj_idx": int(m.obj_idx[row]),
            "class": CLASSES[int(m.cls[row])],
            "lon": float(m.lonlat[row, 0]) if m.lonlat is not None else None,
            "lat": float(m.lonlat[row, 1]) if m.lonlat is not None else None,
        }
        if m.obj_scene is not None:
            match.update(scene=str(m.obj_scene[row]), scene_obj_idx=int(m.obj_scene_idx[row]))
        matches.append(match)
    return {
        "lon": lon,
        "lat": lat,
        "x_m": float(sol.x),
        "y_m": float(sol.y),
        "heading_deg": float((90.0 - theta) % 360.0) if lon is not None else None,  # north: the frame's +y
        "theta_deg": float(theta),
        "scale": float(sol.scale) / unit,
        **place(m, sol.x, sol.y),
        "matches": matches,
    }


def place(m: ObjectMap, x: float, y: float) -> dict:
    """Which scene (and city) a pose at (x, y) of the map's frame lies in, as JSON values: on a scene
    map the map's own (``scene`` None for a map outside the workflow); on a city index the scene of
    the tile whose objects are nearest, with the pose in that scene's own frame (``scene_x_m``,
    ``scene_y_m``: the tile's translation taken off; headings are the same in both frames). Why: a
    city's metres are its tiled frame (x 2,074 m in scene 12 means nothing to a user), and an
    alternative can lie in another scene, or another city, than the pose."""
    if m.kind != "city":
        return {"scene": m.scene, "city": m.cities.get(m.scene) if m.scene is not None else None}
    tile = _tile_at(m, np.array([x, y], float))
    if tile is None:
        return {"scene": None, "city": None, "scene_x_m": None, "scene_y_m": None}
    return {
        "scene": tile.scene,
        "city": m.cities.get(tile.scene),
        "scene_x_m": float(x - tile.offset[0]),
        "scene_y_m": float(y - tile.offset[1]),
    }


def scene_xy(m: ObjectMap, scene: str, x: float, y: float) -> tuple[float, float] | None:
    """A position of a city's tiled frame in ``scene``'s own frame (its tile's translation taken
    off), whichever tile the position lies in; None when the city has no such tile. On a scene map,
    the position as given."""
    if m.kind != "city":
        return float(x), float(y)
    if m.obj_scene is None or str(scene) not in set(m.obj_scene.tolist()):
        return None
    tile = _tile(m, str(scene))
    return None if tile is None else (float(x - tile.offset[0]), float(y - tile.offset[1]))


#: what a prior position is checked against: a fix (or --near) this many times nearer the map read
#: the other way round is reported as lon/lat swapped (as flatlandia score's FAR_SMALLER)
SWAP_NEARER = 5.0


def _metres_to_map(m: ObjectMap, lon: float, lat: float) -> float | None:
    """Great-circle metres from (lon, lat) to the map's nearest object (None without lon/lat)."""
    if m.lonlat is None or not (abs(lon) <= 180 and abs(lat) <= 90):
        return None
    lam, phi = np.radians(m.lonlat[:, 0]), np.radians(m.lonlat[:, 1])
    lam0, phi0 = math.radians(lon), math.radians(lat)
    h = np.sin((phi - phi0) / 2) ** 2 + math.cos(phi0) * np.cos(phi) * np.sin((lam - lam0) / 2) ** 2
    return float(2 * 6371008.8 * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0))).min())


def _far(d: float) -> str:
    return f"{d / 1000:,.0f} km" if d >= 10_000 else f"{d:,.0f} m"


def prior_warnings(m: ObjectMap, gps=None, near=None, radius_m=None) -> list[str]:
    """Warnings (not errors: the answer is still computed) where a prior position cannot be right
    for this map, as ``flatlandia score`` warns on a convention mixed up: lon and lat that look
    swapped (read the other way round, the position lies near the map), or a position farther
    from every map object than its reach (a fix: its 4 sigma plus what a camera sees, the map
    objects the solver searches; ``--near``: its radius): outside the map's area."""
    from flatlandia.solver.priors import Fix

    out = []
    view = Fix.VIEW_M
    for flag, pos, reach, what in (
        (
            "--gps",
            gps,
            None if gps is None else Fix.GATE_SIGMAS * float(gps[2]) + view,
            "4 sigma plus the {view:g} m a camera sees",
        ),
        ("--near", near, radius_m, "--radius-m"),
    ):
        if pos is None or reach is None:
            continue
        lon, lat = float(pos[0]), float(pos[1])
        d = _metres_to_map(m, lon, lat)
        if d is None or d <= reach:
            continue
        swapped = _metres_to_map(m, lat, lon)
        if swapped is not None and swapped * SWAP_NEARER < d and swapped <= max(reach, 1000.0):
            out.append(
                f"{flag} {lon},{lat}: lon and lat look swapped: read as {lat},{lon} it lies {_far(swapped)} "
                f"from the map's nearest object instead of {_far(d)} (give LON,LAT: longitude first)"
            )
        else:
            lo, hi = m.lonlat.min(axis=0), m.lonlat.max(axis=0)
            out.append(
                f"{flag} {lon},{lat} is {_far(d)} from the map's nearest object, beyond its reach ({reach:g} m: "
                f"{what.format(view=view)}): outside the map's area (lon {lo[0]:.5f} to {hi[0]:.5f}, lat "
                f"{lo[1]:.5f} to {hi[1]:.5f})? No pose can lie near it"
            )
    return out


def no_pose_reason(m: ObjectMap, cls, rows: np.ndarray, gps=None) -> str:
    """Why a query (``cls``: its objects' classes; None: a sequence) got no pose. With a fix, the fix
    is named when it ruled out every place (no map object within its 4 sigma, or too few of the
    query's classes near it), so that a fix 262 m off, or with lon/lat swapped, says so."""
    usable = int(np.isin(cls, m.cls[rows]).sum()) if cls is not None and len(rows) else 0
    n = len(cls) if cls is not None else 0
    if gps is None:
        if usable < MIN_OBJECTS:
            return f"only {usable} of the query's {n} objects have a class among the {len(rows)} map objects searched"
        return "no pose explains the query's objects on the map objects searched"
    lon, lat, sigma = (float(v) for v in gps[:3])
    gate = 4.0 * sigma
    where = f"of the fix at {lon}, {lat}"
    ask = "is the fix right? lon/lat swapped?"
    d = _metres_to_map(m, lon, lat)
    if d is not None and d > gate:
        return f"no pose: no map object within 4 sigma ({gate:g} m) {where} (the nearest is {_far(d)} away); {ask}"
    if cls is not None and usable < MIN_OBJECTS:
        return (
            f"no pose: only {usable} of the query's {n} objects have a class among the {len(rows)} map objects "
            f"within reach {where} (4 sigma, {gate:g} m, plus what a camera sees); {ask}"
        )
    return f"no pose within 4 sigma ({gate:g} m) {where} explains the objects on the map; {ask}"


def _check_prior(gps, compass) -> None:
    """InputError unless ``gps`` is (lon, lat, sigma_m > 0) and ``compass`` (heading_deg, sigma_deg > 0)."""
    if compass is not None and gps is None:
        raise InputError("--compass", "a compass heading needs a GPS fix too (--gps and --gps-sigma-m)")
    if gps is not None:
        if len(gps) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in gps):
            raise InputError("--gps", f"{gps} is not lon, lat, sigma_m")
        if abs(gps[0]) > 180 or abs(gps[1]) > 90:
            raise InputError("--gps", f"{gps[:2]} is not lon, lat in degrees")
        if not 0 < gps[2] <= validate.MAX_PRIOR_M:
            raise InputError(
                "--gps-sigma-m", f"{gps[2]} is not a positive number of metres up to {validate.MAX_PRIOR_M:g}"
            )
    if compass is not None:
        if len(compass) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in compass):
            raise InputError("--compass", f"{compass} is not heading_deg, sigma_deg")
        if not 0 < compass[1] <= validate.MAX_COMPASS_SIGMA_DEG:
            raise InputError(
                "--compass-sigma-deg",
                f"{compass[1]} is not a positive number of degrees up to {validate.MAX_COMPASS_SIGMA_DEG:g}",
            )


def fixes(m: ObjectMap, gps, compass=None) -> list:
    """The prior as the solver's :class:`~flatlandia.solver.Fix` in the map's metres: one on a scene
    map; on a city, one per tile whose objects lie near the fix (each tile keeps its scene's
    lon/lat). ``gps``: (lon, lat, sigma_m); ``compass``: (heading_deg clockwise from north, sigma_deg)."""
    from flatlandia import solver

    _check_prior(gps, compass)
    lon, lat, sigma = (float(v) for v in gps)
    theta = hsig = None
    if compass is not None:  # compass: clockwise from north; the solver's theta: counter-clockwise from east
        theta, hsig = math.radians(90.0 - float(compass[0])), float(compass[1])
    probe = solver.Fix(0.0, 0.0, sigma)
    if m.kind == "scene":
        if m.to_xy is None:
            raise InputError(m.path, "--gps needs a map with lon/lat; this one has a local frame")
        centres = np.array([m.to_xy.transform(lon, lat)], float)
    else:
        centres = _near_rows(m, (lon, lat), probe.crop_m)[1]
    return [solver.Fix(float(c[0]), float(c[1]), sigma, theta, hsig) for c in centres]


def localize(
    m: ObjectMap,
    query: Query | dict,
    map_type: str = "gt",
    near: tuple[float, float] | None = None,
    radius_m: float | None = None,
    alternatives: int = ALTERNATIVES,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    rows: np.ndarray | None = None,
) -> dict:
    """One query's pose on a loaded map (:func:`load_map`), as a dict of JSON values.

    ``map_type``: ``gt`` (x/y in metres) or ``depth`` (any unit: the scale is solved for);
    ``near`` (lon, lat) and ``radius_m``: search only the map objects within ``radius_m`` of it (a
    prior position; on a city, in place of the index's regions). Keys: ``found``; the pose ``lon``,
    ``lat`` (None without a geographic frame), ``x_m``, ``y_m`` (the map's metric frame, ``frame``),
    ``heading_deg`` (compass: clockwise from north), ``theta_deg`` (the benchmark's: counter-clockwise
    from east), ``scale`` (metres per query unit; 1 for GT), ``confidence`` (share of the query's
    objects explained, lowered when a distinct pose is nearly as good), ``cost``, ``matches`` (query
    object -> ``obj_idx``, class, lon/lat), ``alternatives`` (the next-best distinct poses with their
    ``cost`` and ``behind``: how far the ranking puts them behind the best), ``priors`` (what the
    solver knew beyond the query and the map), ``searched`` (map objects searched) and ``seconds``
    (the solver's time); ``reason`` when nothing was found; ``status`` and ``probability``
    (:func:`answer_status`; each alternative has its ``probability``). ``gps`` (lon, lat, sigma_m) and
    ``compass`` (heading_deg clockwise from north, sigma_deg): a phone's fix, weighed as a likelihood
    (:func:`fixes`; not with ``near``). ``rows``: search only these rows of a scene map, in this order
    (a proposal: the objects a coarse stage, or the oracle box, proposes; as rule fine_eval does)."""
    from flatlandia.city import search as city_search

    if map_type not in MAP_TYPES:
        raise InputError("--map-type", f"{map_type!r} is not one of {', '.join(MAP_TYPES)}")
    q = query if isinstance(query, Query) else parse_query(query)
    if (near is None) != (radius_m is None):
        raise InputError("--near", "a prior position needs both near (lon, lat) and radius_m")
    if near is not None and not (
        math.isfinite(near[0]) and math.isfinite(near[1]) and abs(near[0]) <= 180 and abs(near[1]) <= 90
    ):
        raise InputError("--near", f"{near} is not lon, lat in degrees")
    if radius_m is not None and not (math.isfinite(radius_m) and 0 < radius_m <= validate.MAX_PRIOR_M):
        raise InputError("--radius-m", f"{radius_m} is not a positive number of metres up to {validate.MAX_PRIOR_M:g}")
    _check_prior(gps, compass)
    if gps is not None and near is not None:
        raise InputError("--gps", "give either a GPS fix (--gps) or a search radius (--near), not both")
    if rows is not None and (m.kind != "scene" or near is not None or gps is not None):
        raise InputError("--proposal", "a proposal (map rows) is searched on a scene map, without --near or --gps")
    xy, unit = _solver_units(q.xy, map_type)
    metric = map_type == "gt"
    priors_used = m.priors_used(map_type)
    t0 = time.perf_counter()
    if gps is not None:
        best, alts, rows = _localize_with_fix(m, xy, q.cls, metric, alternatives, fixes(m, gps, compass), map_type)
        priors_used["gps"] = _gps_used(gps, compass)
    elif m.kind == "city":
        centres = None
        if near is not None:
            rows, centres = _near_rows(m, near, radius_m)
        search = m.search if near is None else _replace(m.search, region_radius_m=float(radius_m))
        found = city_search.localize(
            m.index, xy, q.cls, search, m.settings, m.learned, metric, alternatives, centres=centres
        )
        best, alts, rows = found.solution, found.alternatives, found.rows
    else:
        if rows is None:
            rows = np.arange(len(m.xy)) if near is None else _near_rows(m, near, radius_m)[0]
        found = _solve_rows(m, xy, q.cls, rows, metric, map_type, alternatives)
        best, alts = found.best, found.alternatives
    seconds = time.perf_counter() - t0
    if near is not None:
        priors_used["near"] = {"lon": float(near[0]), "lat": float(near[1]), "radius_m": float(radius_m)}
    out: dict[str, Any] = {"id": q.id, "map": str(m.path), "map_type": map_type, "found": best is not None}
    if best is None:
        out["reason"] = no_pose_reason(m, q.cls, rows, gps)
        pose = dict.fromkeys(("lon", "lat", "x_m", "y_m", "heading_deg", "theta_deg", "scale"))
        out.update(pose, confidence=0.0, cost=None, matches=[], alternatives=[])
    else:
        out.update(_pose(m, best, unit, rows, q), confidence=float(best.confidence), cost=float(best.cost))
        out["alternatives"] = [
            {**_pose(m, a, unit, rows, q), "cost": float(a.cost), "behind": float(a.behind), "probability": _p(a)}
            for a in alts
        ]
    out.update(answer_status(best, m.settings.answer_probability))
    out.update(frame=m.frame, priors=priors_used, searched=int(len(rows)), seconds=seconds)
    out["warnings"] = prior_warnings(m, gps=gps, near=near, radius_m=radius_m)
    return out


def _p(sol) -> float | None:
    """A pose's probability of being within (5 m, 5 deg), None where it has none."""
    p = float(sol.probability)
    return p if math.isfinite(p) else None


def answer_status(best, threshold: float) -> dict:
    """``status`` and ``probability`` of an answer: ``no pose`` (probability 0) without a pose,
    ``ok`` when the pose's calibrated probability of being within (5 m, 5 deg) is at least
    ``threshold`` (``solver.answer_probability``), else ``ambiguous``: the alternatives, each with
    its probability, say where else the camera may be."""
    if best is None:
        return {"status": "no pose", "probability": 0.0}
    p = _p(best)
    return {"status": "ok" if p is None or p >= threshold else "ambiguous", "probability": p}


def _replace(cfg, **changes):
    import dataclasses

    return dataclasses.replace(cfg, **changes)


def _solver_units(xy: np.ndarray, map_type: str) -> tuple[np.ndarray, float]:
    """A local map in the solver's units and the unit: depth maps at a median object range of 1 (the
    scale prior's unit), GT maps as given."""
    if map_type == "depth":
        med = float(np.median(np.hypot(xy[:, 0], xy[:, 1])))
        if abs(med - 1.0) > NORMALISED_TOL:
            return xy / med, med
    return xy, 1.0


def _gps_used(gps, compass) -> dict:
    out = {"lon": float(gps[0]), "lat": float(gps[1]), "sigma_m": float(gps[2])}
    if compass is not None:
        out.update(compass_deg=float(compass[0]), compass_sigma_deg=float(compass[1]))
    return out


def _solve_rows(m: ObjectMap, xy, cls, rows: np.ndarray, metric: bool, map_type: str, alternatives: int, fix=None):
    """The solver on the scene map's ``rows`` with the map's priors over them (none found when fewer
    than 2 objects are searched): one query, with or without a fix."""
    from flatlandia import solver

    if len(rows) < 2:
        return solver.Localization(None)
    priors = m.priors[map_type]
    return solver.localize(
        xy,
        cls,
        m.xy[rows],
        m.cls[rows],
        metric=metric,
        config=m.settings,
        priors=priors.rows(rows) if priors is not None else None,
        alternatives=alternatives,
        fix=fix,
    )


def _localize_with_fix(m: ObjectMap, xy, cls, metric: bool, alternatives: int, fx: list, map_type: str):
    """(best, alternatives, rows searched) of one query with a fix: the map objects within the fix's
    reach, the fix as the solver's likelihood; on a city, each tile the fix falls in, the cheapest
    answer kept."""
    from flatlandia.city import search as city_search

    answers = []
    for fix in fx:
        if m.kind == "city":
            found = city_search.localize(
                m.index, xy, cls, m.search, m.settings, m.learned, metric, alternatives, fix=fix
            )
            answers.append((found.solution, found.alternatives, found.rows))
            continue
        rows = np.flatnonzero(np.hypot(*(m.xy - fix.xy).T) <= fix.crop_m)
        found = _solve_rows(m, xy, cls, rows, metric, map_type, alternatives, fix)
        answers.append((found.best, found.alternatives, rows))
    found = [a for a in answers if a[0] is not None]
    if not found:
        return None, [], answers[0][2] if answers else np.zeros(0, np.int64)
    return min(found, key=lambda a: a[0].cost)


def localize_sequence(
    m: ObjectMap,
    sequence: Sequence | dict,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    alternatives: int = ALTERNATIVES,
    settings=None,
) -> dict:
    """A sequence's anchor pose on a loaded map (depth local maps): :func:`flatlandia.solver.localize_sequence`
    on a scene map, :func:`flatlandia.city.search.localize_sequence` on a city index, with the
    map's priors and an optional fix (``gps``, ``compass`` as :func:`localize`) of the anchor. The
    answer is :func:`localize`'s for the anchor (its ``matches`` are the anchor's objects'), plus
    ``frames``: every frame's pose (``id``, lon, lat, x_m, y_m, heading_deg, theta_deg, scale),
    anchor first. ``settings``: the sequence solver's (config section ``beyond.sequence``; None:
    the schema's defaults)."""
    from flatlandia import solver
    from flatlandia.city import search as city_search

    seq = sequence if isinstance(sequence, Sequence) else parse_sequence(sequence)
    _check_prior(gps, compass)
    units = [_solver_units(f.xy, "depth") for f in seq.frames]
    frames = [(xy, f.cls) for (xy, _), f in zip(units, seq.frames)]
    priors_used = m.priors_used("depth")
    fx = fixes(m, gps, compass) if gps is not None else [None]
    t0 = time.perf_counter()
    answers = []
    for fix in fx:
        if m.kind == "city":
            found, located = city_search.localize_sequence(
                m.index, frames, seq.rel, m.search, m.settings, settings, m.learned, seq.sigma, fix, None, alternatives
            )
            rows = located.rows
        else:
            rows = np.arange(len(m.xy)) if fix is None else np.flatnonzero(np.hypot(*(m.xy - fix.xy).T) <= fix.crop_m)
            priors = m.priors["depth"]
            found = (
                solver.localize_sequence(
                    frames,
                    seq.rel,
                    m.xy[rows],
                    m.cls[rows],
                    m.settings,
                    priors.rows(rows) if priors is not None else None,
                    settings,
                    seq.sigma,
                    fix,
                    alternatives,
                )
                if len(rows) >= 2
                else solver.SequenceLocalization(None)
            )
        answers.append((found, rows))
    good = [a for a in answers if a[0].best is not None]
    found, rows = min(good, key=lambda a: a[0].best.cost) if good else answers[0]
    seconds = time.perf_counter() - t0
    if gps is not None:
        priors_used["gps"] = _gps_used(gps, compass)
    priors_used["sequence"] = {"frames": len(seq.frames)}
    anchor = seq.frames[0]
    out: dict[str, Any] = {"id": anchor.id, "map": str(m.path), "map_type": "depth", "found": found.best is not None}
    if found.best is None:
        out["reason"] = (
            no_pose_reason(m, None, rows, gps)
            if gps is not None
            else "no pose explains the sequence's objects on the map objects searched"
        )
        pose = dict.fromkeys(("lon", "lat", "x_m", "y_m", "heading_deg", "theta_deg", "scale"))
        out.update(pose, confidence=0.0, cost=None, matches=[], alternatives=[], frames=[])
    else:
        out.update(_pose(m, found.best, units[0][1], rows, anchor), confidence=float(found.best.confidence))
        out["cost"] = float(found.best.cost)
        out["alternatives"] = [
            {
                **_pose(m, a, units[0][1], rows, anchor),
                "cost": float(a.cost),
                "behind": float(a.behind),
                "probability": _p(a),
            }
            for a in found.alternatives
        ]
        out["frames"] = []
        for f, (p, (_, unit)) in enumerate(zip(found.frames, units)):
            theta = math.degrees(math.atan2(math.sin(p.theta), math.cos(p.theta)))
            lon, lat = _lonlat_of(m, np.array([p.x, p.y]))
            out["frames"].append(
                {
                    "id": seq.frames[f].id,
                    "lon": lon,
                    "lat": lat,
                    "x_m": float(p.x),
                    "y_m": float(p.y),
                    "heading_deg": float((90.0 - theta) % 360.0) if lon is not None else None,
                    "theta_deg": float(theta),
                    "scale": float(p.scale) / unit,
                    **place(m, p.x, p.y),
                }
            )
    out.update(answer_status(found.best, m.settings.answer_probability))
    out.update(frame=m.frame, priors=priors_used, searched=int(len(rows)), seconds=seconds)
    out["warnings"] = prior_warnings(m, gps=gps)
    return out


def localize_file(
    map_path: str | Path,
    query_path: str | Path | None,
    map_type: str | None = None,
    near: tuple[float, float] | None = None,
    radius_m: float | None = None,
    alternatives: int = ALTERNATIVES,
    gps: tuple[float, float, float] | None = None,
    compass: tuple[float, float] | None = None,
    sequence_path: str | Path | None = None,
    **load_args,
) -> dict:
    """``flatlandia localize``: the queries of a JSON file on a map file. One query in: its answer
    (:func:`localize`); a file of many: ``{"results": [answers]}``; a sequence file instead
    (``sequence_path``, depth maps): its anchor's answer with every frame's pose
    (:func:`localize_sequence`). ``gps``/``compass``: a fix of the query (of the sequence's anchor).
    The input is read and checked before the map loads (a bad query fails in a second).
    ``map_type`` None: ``depth`` for a sequence (the only type it takes), else ``gt``."""
    if map_type is None:
        map_type = "depth" if sequence_path is not None else "gt"
    if map_type not in MAP_TYPES:
        raise InputError("--map-type", f"{map_type!r} is not one of {', '.join(MAP_TYPES)}")
    _check_prior(gps, compass)
    if (query_path is None) == (sequence_path is None):
        raise InputError("--query", "give a query file (--query) or a sequence file (--sequence), one of them")
    if sequence_path is not None:
        if map_type != "depth":
            raise InputError("--map-type", "a sequence is of depth local maps: --map-type depth")
        if near is not None:
            raise InputError("--near", "a sequence takes a GPS fix (--gps), not --near")
        seq = read_sequence(sequence_path)
        return localize_sequence(load_map(map_path, **load_args), seq, gps, compass, alternatives)
    queries, many = read_queries(query_path)
    m = load_map(map_path, **load_args)
    results = [localize(m, q, map_type, near, radius_m, alternatives, gps, compass) for q in queries]
    return {"results": results} if many else results[0]


def dumps(result: Any) -> str:
    """JSON text of an answer (non-finite numbers as null)."""

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(result), indent=1)
