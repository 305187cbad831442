"""The maps a query is localized on, loaded once (:func:`load_map`), and where a position of a map lies.

A scene's reference map (the workflow's, or any GeoParquet / GeoJSON of classed points) comes with
the solver's priors a workflow run gives it (:func:`set_training_priors`); a city index with its
map's lon/lat, each tile in its scene's frame (:func:`place`, :func:`scene_xy`, :func:`lonlat_of`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flatlandia import geo, paths, vocabulary
from flatlandia.classes import CLASSES
from flatlandia.localize.query_files import class_ids
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

# the solver loads numba (seconds; docs/measurements.md, "Start-up costs"): only a loaded map needs it
if TYPE_CHECKING:
    import pandas as pd

    from flatlandia import solver
    from flatlandia.city.index import ViewIndex
    from flatlandia.city.search import SearchConfig

MAP_TYPES = vocabulary.MAP_TYPES


#: class properties of a map, in the order they are looked for (labels before ids)
LABEL_KEYS = ("class_label", "class", "label")


ID_KEY = "class_id"


#: lon/lat column names of a map table
LON_KEYS, LAT_KEYS = ("lon", "longitude", "lng"), ("lat", "latitude")


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
    built once: a transformer costs far more than a query's few points (docs/measurements.md,
    "Start-up costs")."""
    from pyproj import CRS, Transformer

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
        return class_ids(df[key].tolist(), path, "object", ids=False)
    if ID_KEY in df.columns:
        return class_ids(df[ID_KEY].tolist(), path, "object", ids=True)
    raise InputError(path, f"no class property: expected one of {', '.join(LABEL_KEYS + (ID_KEY,))}")


def _read_table(path: Path) -> tuple[pd.DataFrame, dict]:
    """A map table from Parquet (its ``flatlandia`` metadata: the workflow's frame) or GeoJSON."""
    import pandas as pd

    from flatlandia.plumbing import files

    if path.suffix.lower() == ".parquet":
        try:
            df = validate.read_parquet(  # bounded on what it decodes to, not only on disk
                path, validate.MAX_MAP_OBJECTS, validate.MAX_MAP_BYTES, "objects", ("MAX_MAP_OBJECTS", "MAX_MAP_BYTES")
            ).to_pandas()
            meta = files.read_parquet_metadata(path)
        except InputError:
            raise
        except Exception as e:  # pyarrow raises several types for files that are not Parquet
            raise InputError(
                path, f"not a readable Parquet file ({type(e).__name__}: {validate.one_line(e)})"
            ) from None
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
        raise InputError(
            path, f"could not read its point geometries ({type(e).__name__}: {validate.one_line(e)})"
        ) from None


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
        validate.lonlat_degrees(lonlat, path)
        if ours:  # the workflow's map: its own frame and metres, as the benchmark reads them
            lon0, lat0 = origin
            xy = _numbers(df, ["x_m", "y_m"], path)
        else:
            lon0, lat0 = _centre(lonlat)
        to_lonlat, to_xy = _transformers(lon0, lat0)
        if not ours:
            xy = np.column_stack(to_xy.transform(lonlat[:, 0], lonlat[:, 1]))
        elif np.isfinite(xy).all():  # the metadata must describe the map's own lon/lat and metres
            validate.frame_matches(lonlat, xy, lambda ll: np.column_stack(to_xy.transform(*ll.T)), origin, path)
        frame = f"transverse Mercator at lon {lon0:.7f}, lat {lat0:.7f} (x east, y north, metres)"
    if not np.isfinite(xy).all():
        raise InputError(path, "some objects have no finite position")
    results, scene, queries_path, learned_auto = _workflow_paths(path)
    settings = solver.SolverConfig.of(settings)
    m = ObjectMap(path, "scene", obj, cls, xy, lonlat, settings, frame, to_lonlat, to_xy, scene=scene)
    m.learned_path = learned_auto if learned == "auto" else (Path(learned) if learned else None)
    m.learned = solver.LearnedPriors.read(m.learned_path) if m.learned_path else None
    training = read_training(queries_path, obj) if queries_path is not None else None
    set_training_priors(m, training, queries_path)
    if scene is not None:
        m.cities = scene_cities(results)
    return m


def _centre(lonlat: np.ndarray) -> tuple[float, float]:
    """The frame origin of a map without one (:func:`flatlandia.geo.frame_for`: its box's centre),
    its longitudes taken around its first object's (:func:`~flatlandia.plumbing.validate.lon_offset`):
    a map across the antimeridian is centred on it, not on the Greenwich meridian half a turn away."""
    from flatlandia import geo

    east = validate.lon_offset(lonlat[:, 0], float(lonlat[0, 0]))
    f = geo.frame_for(np.column_stack([east, lonlat[:, 1]]))
    return float(validate.lon_offset(f.lon0 + lonlat[0, 0], 0.0)), f.lat0


def read_training(path: Path, obj_idx: np.ndarray) -> pd.DataFrame:
    """A workflow map's queries table (results/{scene}/queries/queries.parquet), the training cameras
    its priors come from, through the door ``flatlandia score`` reads it by (a regular Parquet file
    within its bounds; each camera finite, every object it saw one of the map's ``obj_idx``:
    :func:`flatlandia.plumbing.validate.ground_truth`)."""
    q = validate.read_table(
        path, validate.MAX_QUERIES, validate.MAX_QUERY_TABLE_BYTES, ("MAX_QUERIES", "MAX_QUERY_TABLE_BYTES")
    )
    tokens = q["token"].astype(str).to_numpy() if "token" in q.columns else []
    validate.ground_truth(q, path, lambda i: f"row {i + 1} (token {validate.shown(tokens[i])})", obj_idx)
    return q


def scene_cities(results: Path) -> dict:
    """scene -> its city's name, from a results folder's ``tables/dataset_stats_per_scene.parquet``
    (rule dataset_stats; empty where it is missing or unreadable: the answers then give no city)."""

    table = paths.within(results, paths.BENCHMARK_RECORD)
    try:  # through the Parquet door: a results folder is a user's
        t = validate.read_table(table, validate.MAX_SCENES, validate.MAX_MAP_BYTES, columns=["scene", "city"])
    except Exception:  # missing, or not the table: a city name is a courtesy, not needed for a pose
        return {}
    return dict(zip(t["scene"].astype(str), t["city"].astype(str)))


def set_training_priors(m: ObjectMap, training: pd.DataFrame | None, source: Path | None = None) -> None:
    """A scene map's priors per map type, as rule fine_eval gives them: the cameras of ``training``'s
    train split and what they saw (columns ``split``, ``x_m``, ``y_m``, ``theta_deg``, ``ref_idx``:
    the workflow's queries.parquet, or an export's ground_truth.csv read so), for depth maps with
    the map's learned priors; None: the learned scale prior alone. ``source``: where they came from."""
    from flatlandia import solver

    ref = pd_frame(m.obj_idx, m.scene)  # the scene names its depth maps' bearing correction
    for map_type in MAP_TYPES:  # as rule fine_eval: cameras and co-visibility; depth maps the learned priors
        lp = m.learned if map_type == "depth" else None
        if training is not None:
            m.priors[map_type] = solver.scene_priors(ref, training, m.settings, lp)
        else:
            m.priors[map_type] = solver.with_learned(solver.TrainingPriors(), lp) if lp is not None else None
    cams = m.priors["gt"].cameras if m.priors["gt"] is not None else None
    m.cameras = 0 if cams is None else len(cams)
    m.queries_path = source if training is not None else None


def pd_frame(obj_idx, scene: str | None = None) -> pd.DataFrame:
    import pandas as pd

    df = pd.DataFrame({"obj_idx": np.asarray(obj_idx, np.int64)})
    return df if scene is None else df.assign(scene=str(scene))


def _city_map(path: Path, settings, learned, search) -> ObjectMap:
    """A city index (one ``.npz`` of ``results/city/{n}/index``) and, beside it, its map's lon/lat."""
    from flatlandia import solver
    from flatlandia.city import search as city_search
    from flatlandia.city.index import ViewIndex

    try:
        ix = ViewIndex.load(path)  # checked there (flatlandia.plumbing.validate.city_index)
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
        from flatlandia.solver.learned_priors import read_map_size

        m.learned, m.map_size_path = m.learned.with_map_size(read_map_size(correction)), correction
    table = city_dir / "map.parquet"
    if path.parent.name == "index" and table.is_file():
        try:
            t = validate.read_parquet(
                table,
                validate.MAX_INDEX_OBJECTS,
                validate.MAX_INDEX_BYTES,
                "objects",
                ("MAX_INDEX_OBJECTS", "MAX_INDEX_BYTES"),
                columns=["city", "scene", "obj_idx", "scene_obj_idx", "lon", "lat"],
            ).to_pandas()
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


def lonlat_of(m: ObjectMap, xy: np.ndarray) -> tuple[float | None, float | None]:
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


def near_rows(m: ObjectMap, near: tuple[float, float], radius_m: float) -> tuple[np.ndarray, np.ndarray]:
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


def metres_to_map(m: ObjectMap, lon: float, lat: float) -> float | None:
    """Great-circle metres from (lon, lat) to the map's nearest object (None without lon/lat)."""
    if m.lonlat is None or not (abs(lon) <= 180 and abs(lat) <= 90):
        return None
    lam, phi = np.radians(m.lonlat[:, 0]), np.radians(m.lonlat[:, 1])
    lam0, phi0 = math.radians(lon), math.radians(lat)
    h = np.sin((phi - phi0) / 2) ** 2 + math.cos(phi0) * np.cos(phi) * np.sin((lam - lam0) / 2) ** 2
    return float(2 * 6371008.8 * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0))).min())
