"""What every kind of map a query is localized on answers: :class:`ObjectMap`, the methods the
localizer calls (solve, gps_fixes, answers, batch, answer_figure), and never which kind a map is.

Each kind is one class (:class:`~flatlandia.localize.scene_map.SceneMap`, a scene's reference map;
:class:`~flatlandia.localize.city_map.CityMap`, a city index), chosen once where the file is read
(:func:`flatlandia.localize.maps.load_map`). Why: a map's kind was a string branched on at eleven
places in four files, and adding a kind meant finding all of them (issue 46). A kind holds the
fields it needs; the base class the ones every map has (the objects, the frame, the solver's
settings and the priors it was given) and the answers of a map with no geographic frame.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

import numpy as np

from flatlandia import geo, paths
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

# the solver loads numba (seconds; docs/measurements.md, "Start-up costs"): only a loaded map needs it
if TYPE_CHECKING:
    from flatlandia import solver


class Found(NamedTuple):
    """One search's answer on a map: the best pose (None: none found), the next-best distinct
    poses, best first, and the map rows searched (what a solution's inliers index)."""

    best: Any
    alternatives: list
    rows: np.ndarray


@dataclass(kw_only=True)
class ObjectMap(abc.ABC):
    """A loaded map: its objects (map rows), its metric frame, the solver's settings and what the
    solver knows beyond the query (training cameras, learned priors). A kind subclasses it with
    its fields, how it is read (:meth:`read`) and how a query is searched on it (:meth:`locate`,
    :meth:`locate_sequence`); the rest has the answers of a map of one frame without lon/lat,
    which a kind with a geographic frame or many scenes overrides."""

    path: Path
    obj_idx: np.ndarray  # (N,) the map's object ids
    cls: np.ndarray  # (N,) class ids
    xy: np.ndarray  # (N, 2) metres of the map's frame
    lonlat: np.ndarray | None  # (N, 2) degrees, None without a geographic frame
    settings: solver.SolverConfig
    frame: str  # what the metric frame is, in words
    learned: solver.LearnedPriors | None = None  # depth maps'
    learned_path: Path | None = None
    learned_gt: solver.LearnedPriors | None = None  # GT maps' (their answers' calibration)
    learned_gt_path: Path | None = None
    queries_path: Path | None = None  # where the training cameras came from
    cameras: int = 0  # training cameras among the priors
    cities: dict = field(default_factory=dict)  # scene -> its city's name, where the results folder says

    #: the kind in words, for records and messages; no behaviour hangs on it
    kind: ClassVar[str]
    #: the file suffixes this kind reads (:func:`flatlandia.localize.maps.load_map` offers a file
    #: to the first kind that names its suffix), and the kind in the reader's message for others
    suffixes: ClassVar[tuple[str, ...]] = ()
    described: ClassVar[str] = ""
    #: whether a proposal (map rows, as rule fine_eval searches them) can be searched on it
    takes_rows: ClassVar[bool] = False
    #: whether it holds many scenes, each in its own frame: a batch's --city, whose poses
    #: :meth:`scene_xy` moves into each query's own scene
    tiled: ClassVar[bool] = False

    @classmethod
    @abc.abstractmethod
    def read(cls, path: Path, settings, learned, search) -> ObjectMap:
        """The map of a file this kind reads (:attr:`suffixes`): ``settings`` the solver's,
        ``learned`` the learned priors (``"auto"``, a path or None), ``search`` a city's search
        settings (a kind that searches no index ignores them). InputError for a bad file."""

    @abc.abstractmethod
    def locate(
        self,
        xy: np.ndarray,
        cls: np.ndarray,
        map_type: str,
        alternatives: int,
        *,
        rows: np.ndarray | None = None,
        near: tuple[float, float] | None = None,
        radius_m: float | None = None,
        fix: solver.Fix | None = None,
    ) -> Found:
        """One query's pose (its objects in the solver's units): the whole map, or only ``rows``
        (a proposal, where :attr:`takes_rows`), the objects within ``radius_m`` of lon/lat ``near``
        (:meth:`near_rows`'s, which refuses a map without lon/lat), or the reach of a phone's
        ``fix`` (one of :func:`~flatlandia.localize.gps_fixes.fixes`, weighed as a likelihood)."""

    @abc.abstractmethod
    def locate_sequence(
        self, frames: list, rel, sigma, settings, alternatives: int, fix: solver.Fix | None = None
    ) -> tuple[solver.SequenceLocalization, np.ndarray]:
        """(a sequence's answer, the map rows searched): ``frames`` (xy, cls) in the solver's units,
        anchor first, ``rel`` and ``sigma`` the odometry, ``settings`` the sequence solver's."""

    def priors_used(self, map_type: str) -> dict:
        """What the solver knew beyond the query and the map, for one map type."""
        lp, lp_path = (
            (self.learned, self.learned_path) if map_type == "depth" else (self.learned_gt, self.learned_gt_path)
        )
        return {
            "training_cameras": int(self.cameras),
            "cameras_from": str(self.queries_path) if self.queries_path and self.cameras else None,
            "learned_from": str(lp_path) if lp is not None and lp_path else None,
            "scale_prior": bool(lp is not None and lp.scale is not None),
            "verifier": bool(lp is not None and lp.verifier is not None and self.cameras > 0),
        }

    def near_rows(self, near: tuple[float, float], radius_m: float, flag: str = "--near") -> tuple:
        """(map rows within ``radius_m`` of lon/lat ``near``, (K, 2) the prior's position in the
        map's metres, one per frame it falls in); ``flag`` names the option in the error of a map
        without lon/lat."""
        raise InputError(self.path, f"{flag} needs a map with lon/lat; this one has a local frame")

    def lonlat_of(self, xy: np.ndarray) -> tuple[float | None, float | None]:
        """lon/lat of a position of the map's frame (Nones without a geographic frame)."""
        return None, None

    def place(self, x: float, y: float) -> dict:
        """Which scene (and city) a pose at (x, y) of the map's frame lies in, as JSON values."""
        return {"scene": None, "city": None}

    def scene_xy(self, scene: str, x: float, y: float) -> tuple[float, float] | None:
        """A position of the map's frame in ``scene``'s own frame (None where the map has no such
        scene): a map of one frame gives it as it is."""
        return float(x), float(y)

    def object_place(self, row: int) -> dict:
        """What a match adds about its map object beyond its id, class and lon/lat (a city: the
        scene it comes from and its id there)."""
        return {}

    @property
    def geographic(self) -> bool:
        """Whether the map's metres are x east, y north (a drawing labels its axes so)."""
        return False

    def framed(self, pts: np.ndarray) -> np.ndarray:
        """The points a drawing of an answer (``pts``: its pose, objects, alternatives) frames:
        with the whole map."""
        return np.vstack([pts, self.xy])


def metres_to_map(m: ObjectMap, lon: float, lat: float) -> float | None:
    """Great-circle metres from (lon, lat) to the map's nearest object (None without lon/lat)."""
    if m.lonlat is None or not (abs(lon) <= 180 and abs(lat) <= 90):
        return None
    lam, phi = np.radians(m.lonlat[:, 0]), np.radians(m.lonlat[:, 1])
    lam0, phi0 = math.radians(lon), math.radians(lat)
    h = np.sin((phi - phi0) / 2) ** 2 + math.cos(phi0) * np.cos(phi) * np.sin((lam - lam0) / 2) ** 2
    return float(2 * 6371008.8 * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0))).min())


def transformers(lon0: float, lat0: float):
    """(metres -> lon/lat, lon/lat -> metres) of a scene frame (:class:`flatlandia.geo.MetricFrame`),
    built once: a transformer costs far more than a query's few points (docs/measurements.md,
    "Start-up costs")."""
    from pyproj import CRS, Transformer

    frame = geo.MetricFrame(lon0, lat0)
    crs = CRS.from_proj4(frame.proj4)
    wgs = CRS.from_epsg(4326)
    return Transformer.from_crs(crs, wgs, always_xy=True), Transformer.from_crs(wgs, crs, always_xy=True)


def scene_cities(results: Path) -> dict:
    """scene -> its city's name, from a results folder's ``tables/dataset_stats_per_scene.parquet``
    (rule dataset_stats; empty where it is missing or unreadable: the answers then give no city)."""

    table = paths.within(results, paths.BENCHMARK_RECORD)
    try:  # through the Parquet door: a results folder is a user's
        t = validate.read_table(table, validate.MAX_SCENES, validate.MAX_MAP_BYTES, columns=["scene", "city"])
    except Exception:  # missing, or not the table: a city name is a courtesy, not needed for a pose
        return {}
    return dict(zip(t["scene"].astype(str), t["city"].astype(str)))
