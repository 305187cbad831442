"""A scene's reference map as the localizer searches it (:class:`SceneMap`): the workflow's
``results/{scene}/maps/reference_map.*``, or any GeoParquet / GeoJSON of classed points, one
metric frame, searched whole (or a proposal's rows, or near a prior position) by
:func:`flatlandia.solver.locate`, the function rule fine_eval calls, with the priors a workflow run
gives it (:func:`set_training_priors`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flatlandia import paths, vocabulary
from flatlandia.classes import CLASSES
from flatlandia.localize import map_tables
from flatlandia.localize.object_map import Found, ObjectMap, scene_cities, transformers
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

# the solver loads numba (seconds; docs/measurements.md, "Start-up costs"): only a loaded map needs it
if TYPE_CHECKING:
    import pandas as pd


@dataclass(kw_only=True)
class SceneMap(ObjectMap):
    """A scene's reference map: its objects in one metric frame (transverse Mercator about its
    origin, or a local frame without lon/lat) and, per map type, the solver's priors over them."""

    to_lonlat: Any = None  # Transformer metres -> lon/lat (None: no geographic frame)
    to_xy: Any = None  # and back
    scene: str | None = None  # the workflow's scene (None: a map from elsewhere)
    priors: dict = field(default_factory=dict)  # map type -> solver.TrainingPriors over the rows

    kind = "scene"
    suffixes = (".parquet", ".geojson", ".json")
    described = "a reference map (.parquet, .geojson)"
    takes_rows = True

    @classmethod
    def read(cls, path: Path, settings, learned, search=None) -> SceneMap:
        """A scene's reference map (the workflow's, or any table of classed points); ``search``
        is a city's and unused."""
        if path.stat().st_size == 0:
            raise InputError(path, "file is empty")
        return _read(path, settings, learned)

    def locate(self, xy, cls, map_type, alternatives, *, rows=None, near=None, radius_m=None, fix=None) -> Found:
        """The solver on the map's rows: all, a proposal's (``rows``), those near a prior position
        or within a fix's reach (the fix as the solver's likelihood)."""
        if fix is not None:
            rows = np.flatnonzero(np.hypot(*(self.xy - fix.xy).T) <= fix.crop_m)
        elif rows is None:
            rows = np.arange(len(self.xy)) if near is None else self.near_rows(near, radius_m)[0]
        found = self._solve_rows(xy, cls, rows, map_type, alternatives, fix)
        return Found(found.best, found.alternatives, rows)

    def _solve_rows(self, xy, cls, rows: np.ndarray, map_type: str, alternatives: int, fix=None):
        """The solver on the map's ``rows`` with the map's priors over them (none found when fewer
        than 2 objects are searched): one query, with or without a fix."""
        from flatlandia import solver

        if len(rows) < 2:
            return solver.Localization(None)
        priors = self.priors[map_type]
        return solver.locate(
            xy,
            cls,
            self.xy[rows],
            self.cls[rows],
            metric=map_type == "gt",
            config=self.settings,
            priors=priors.rows(rows) if priors is not None else None,
            alternatives=alternatives,
            fix=fix,
        )

    def locate_sequence(self, frames, rel, sigma, settings, alternatives, fix=None):
        """:func:`flatlandia.solver.locate_sequence` on the whole map, or within a fix's reach,
        with the depth maps' priors."""
        from flatlandia import solver

        rows = np.arange(len(self.xy)) if fix is None else np.flatnonzero(np.hypot(*(self.xy - fix.xy).T) <= fix.crop_m)
        priors = self.priors["depth"]
        if len(rows) < 2:
            return solver.SequenceLocalization(None), rows
        found = solver.locate_sequence(
            frames,
            rel,
            self.xy[rows],
            self.cls[rows],
            self.settings,
            priors.rows(rows) if priors is not None else None,
            settings,
            sigma,
            fix,
            alternatives,
        )
        return found, rows

    def near_rows(self, near, radius_m, flag="--near"):
        """The map rows within ``radius_m`` of lon/lat ``near`` and the position in the map's metres."""
        if self.to_xy is None:
            return super().near_rows(near, radius_m, flag)
        c = np.array(self.to_xy.transform(float(near[0]), float(near[1])), float)
        return np.flatnonzero(np.hypot(*(self.xy - c).T) <= radius_m), c[None]

    def lonlat_of(self, xy):
        if self.to_lonlat is None:
            return None, None
        lon, lat = self.to_lonlat.transform(float(xy[0]), float(xy[1]))
        return float(lon), float(lat)

    def place(self, x, y):
        """The map's own scene (None for a map outside the workflow) and its city."""
        return {"scene": self.scene, "city": self.cities.get(self.scene) if self.scene is not None else None}

    @property
    def geographic(self) -> bool:
        return self.to_lonlat is not None


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


def _read(path: Path, settings, learned) -> SceneMap:
    """A scene's reference map from its table: its classes, ids, lon/lat and metres checked, its
    frame (the workflow's metadata, a local frame, or one centred on the map), its priors."""
    from flatlandia import solver

    df, meta = map_tables.read_table(path)
    if len(df) == 0:
        raise InputError(path, "the map holds no objects")
    origin = validate.frame_origin(meta, path)  # metadata that is no object, or a lon0 that is no degree: refused
    meta = meta or {}
    cls = map_tables.table_classes(df, path)
    validate.class_counts(cls, path, CLASSES)  # the solver's candidates grow with the objects of a class
    obj = map_tables.numbers(df, ["obj_idx"], path, np.int64)[:, 0] if "obj_idx" in df.columns else np.arange(len(df))
    validate.unique_ids(obj, path)
    lon, lat = map_tables.pick(df.columns, map_tables.LON_KEYS), map_tables.pick(df.columns, map_tables.LAT_KEYS)
    lonlat = map_tables.numbers(df, [lon, lat], path) if lon and lat else None
    ours = origin is not None and {"x_m", "y_m"} <= set(df.columns)
    to_lonlat = to_xy = None
    if meta.get("frame") == "local" and {"x_m", "y_m"} <= set(df.columns):  # an images scene without GPS
        xy, lonlat, frame = (
            map_tables.numbers(df, ["x_m", "y_m"], path),
            None,
            f"local ({meta.get('unit', 'SfM unit')}), no lon/lat",
        )
    elif lonlat is None:
        raise InputError(path, "no lon/lat: expected lon and lat columns or properties, or point geometries")
    else:
        validate.lonlat_degrees(lonlat, path)
        if ours:  # the workflow's map: its own frame and metres, as the benchmark reads them
            lon0, lat0 = origin
            xy = map_tables.numbers(df, ["x_m", "y_m"], path)
        else:
            lon0, lat0 = _centre(lonlat)
        to_lonlat, to_xy = transformers(lon0, lat0)
        if not ours:
            xy = np.column_stack(to_xy.transform(lonlat[:, 0], lonlat[:, 1]))
        elif np.isfinite(xy).all():  # the metadata must describe the map's own lon/lat and metres
            validate.frame_matches(lonlat, xy, lambda ll: np.column_stack(to_xy.transform(*ll.T)), origin, path)
        frame = f"transverse Mercator at lon {lon0:.7f}, lat {lat0:.7f} (x east, y north, metres)"
    if not np.isfinite(xy).all():
        raise InputError(path, "some objects have no finite position")
    results, scene, queries_path, learned_auto = _workflow_paths(path)
    settings = solver.SolverConfig.of(settings)
    m = SceneMap(
        path=path,
        obj_idx=obj,
        cls=cls,
        xy=xy,
        lonlat=lonlat,
        settings=settings,
        frame=frame,
        to_lonlat=to_lonlat,
        to_xy=to_xy,
        scene=scene,
    )
    m.learned_path = learned_auto if learned == "auto" else (Path(learned) if learned else None)
    m.learned = solver.LearnedPriors.read(m.learned_path) if m.learned_path else None
    if learned == "auto" and learned_auto is not None and results is not None:  # GT maps' calibration beside it
        gt = paths.within(results, paths.solver_priors_gt(vocabulary.WHOLE))
        m.learned_gt_path = gt if gt.is_file() else None
        m.learned_gt = solver.LearnedPriors.read(gt) if m.learned_gt_path else None
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


def set_training_priors(m: SceneMap, training: pd.DataFrame | None, source: Path | None = None) -> None:
    """A scene map's priors per map type, as rule fine_eval gives them: the cameras of ``training``'s
    train split and what they saw (columns ``split``, ``x_m``, ``y_m``, ``theta_deg``, ``ref_idx``:
    the workflow's queries.parquet, or an export's ground_truth.csv read so), for depth maps with
    the map's learned priors, for GT maps with their calibration; None: the learned priors alone. ``source``: where they came from."""
    from flatlandia import solver

    ref = pd_frame(m.obj_idx, m.scene)  # the scene names its depth maps' bearing correction
    for map_type in vocabulary.MAP_TYPES:  # as rule fine_eval: cameras and co-visibility; depth maps the learned priors
        lp = m.learned if map_type == "depth" else m.learned_gt
        if training is not None:
            m.priors[map_type] = solver.scene_priors(ref, training, m.settings, lp)
        else:
            m.priors[map_type] = solver.with_learned(solver.TrainingPriors(), lp) if lp is not None else None
    cams = m.priors["gt"].cameras if m.priors["gt"] is not None else None
    m.cameras = 0 if cams is None else len(cams)
    m.queries_path = source if training is not None else None


def pd_frame(obj_idx, scene: str | None = None) -> pd.DataFrame:
    """The map table the solver's priors read (``obj_idx``; ``scene``: its depth maps' bearing correction)."""
    import pandas as pd

    df = pd.DataFrame({"obj_idx": np.asarray(obj_idx, np.int64)})
    return df if scene is None else df.assign(scene=str(scene))
