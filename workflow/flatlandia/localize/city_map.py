"""A city index as the localizer searches it (:class:`CityMap`): one ``.npz`` of
``results/city/{n}/index`` searched by :func:`flatlandia.city.search.search_city` (the index
proposes regions, the solver searches them with the training views there as priors), with its
map's lon/lat from the city's ``map.parquet`` beside the index. A tiled city: each tile is a
published scene moved by a translation and keeps its lon/lat (:class:`Tile`), so a pose is also
given in its scene's own frame (:meth:`CityMap.place`, :meth:`CityMap.scene_xy`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flatlandia import geo, paths, vocabulary
from flatlandia.localize.object_map import Found, ObjectMap, scene_cities, transformers
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

# the solver and the city search load numba (seconds): only a loaded map needs them
if TYPE_CHECKING:
    from flatlandia.city.index import ViewIndex
    from flatlandia.city.search import SearchConfig


@dataclass
class Tile:
    """Where a scene's tile of a tiled city lies: its metric frame and the translation into the city."""

    scene: str
    to_lonlat: Any  # Transformer, tile metres -> lon/lat
    to_xy: Any  # Transformer, lon/lat -> tile metres
    offset: np.ndarray  # (2,) city = tile + offset


@dataclass(kw_only=True)
class CityMap(ObjectMap):
    """A city index: its objects in the city's tiled frame, the index the search proposes regions
    from, the search's settings and, with the city's map beside it, each object's scene."""

    index: ViewIndex
    search: SearchConfig
    map_size_path: Path | None = None  # the map-size correction of the probability (rule city_calibration)
    tiles: dict = field(default_factory=dict)  # scene -> Tile (lazily)
    obj_scene: np.ndarray | None = None  # scene of each row
    obj_scene_idx: np.ndarray | None = None  # each row's obj_idx in its scene

    kind = "city"
    suffixes = (".npz",)
    described = "a city index (.npz, folder)"
    tiled = True

    @classmethod
    def read(cls, path: Path, settings, learned, search) -> CityMap:
        """A city index and, beside it, its map's lon/lat."""
        return _read(path, settings, learned, search)

    def priors_used(self, map_type: str) -> dict:
        """The scene map's record, and where the map-size correction of a depth map's probability
        came from."""
        lp = self.learned if map_type == "depth" else None
        return {
            **super().priors_used(map_type),
            "map_size_from": str(self.map_size_path) if lp is not None and self.map_size_path else None,
        }

    def locate(self, xy, cls, map_type, alternatives, *, rows=None, near=None, radius_m=None, fix=None) -> Found:
        """The city search: the index's regions, the tiles a prior position falls in (``near``,
        ``radius_m`` in place of the index's radius) or a fix's region (``fix``, as its likelihood
        too). ``rows`` is not taken (:attr:`takes_rows`)."""
        from flatlandia.city import search as city_search

        metric = map_type == "gt"
        if fix is not None:
            found = city_search.search_city(
                self.index, xy, cls, self.search, self.settings, self.learned, metric, alternatives, fix=fix
            )
            return Found(found.solution, found.alternatives, found.rows)
        centres = None
        if near is not None:
            centres = self.near_rows(near, radius_m)[1]
        search = self.search if near is None else dataclasses.replace(self.search, region_radius_m=float(radius_m))
        found = city_search.search_city(
            self.index, xy, cls, search, self.settings, self.learned, metric, alternatives, centres=centres
        )
        return Found(found.solution, found.alternatives, found.rows)

    def locate_sequence(self, frames, rel, sigma, settings, alternatives, fix=None):
        """:func:`flatlandia.city.search.search_city_sequence` (a fix: its region)."""
        from flatlandia.city import search as city_search

        found, located = city_search.search_city_sequence(
            self.index, frames, rel, self.search, self.settings, settings, self.learned, sigma, fix, None, alternatives
        )
        return found, located.rows

    def near_rows(self, near, radius_m, flag="--near"):
        """The rows within ``radius_m`` of lon/lat ``near`` and the position in the city's metres,
        one per tile that has such objects (each tile keeps its scene's lon/lat: a prior position
        falls in the tiles whose objects are near it). Without the city's lon/lat an InputError
        that names --near whatever ``flag`` (as it always has)."""
        if self.obj_scene is None:
            raise InputError(self.path, "--near needs the city's lon/lat (its map.parquet beside the index folder)")
        lon, lat = float(near[0]), float(near[1])
        k = 6371008.8 * math.pi / 180
        d = np.hypot((self.lonlat[:, 0] - lon) * k * math.cos(math.radians(lat)), (self.lonlat[:, 1] - lat) * k)
        centres = []
        for scene in sorted(set(self.obj_scene[d <= radius_m + 1.0].tolist())):
            tile = self._tile(scene)
            if tile is not None:
                centres.append(np.array(tile.to_xy.transform(lon, lat), float) + tile.offset)
        centres = np.array(centres).reshape(-1, 2)
        rows = np.unique(np.concatenate([self.index.obj_tree.query_ball_point(c, radius_m) for c in centres] + [[]]))
        return rows.astype(np.int64), centres

    def lonlat_of(self, xy):
        """lon/lat through the tile the position lies in (Nones without the city's lon/lat)."""
        tile = self._tile_at(xy)
        if tile is None:
            return None, None
        lon, lat = tile.to_lonlat.transform(float(xy[0] - tile.offset[0]), float(xy[1] - tile.offset[1]))
        return float(lon), float(lat)

    def place(self, x, y):
        """The scene of the tile whose objects are nearest, with the pose in that scene's own frame
        (``scene_x_m``, ``scene_y_m``: the tile's translation taken off; headings are the same in
        both frames). Why: a city's metres are its tiled frame (x 2,074 m in scene 12 means nothing
        to a user), and an alternative can lie in another scene, or another city, than the pose."""
        tile = self._tile_at(np.array([x, y], float))
        if tile is None:
            return {"scene": None, "city": None, "scene_x_m": None, "scene_y_m": None}
        return {
            "scene": tile.scene,
            "city": self.cities.get(tile.scene),
            "scene_x_m": float(x - tile.offset[0]),
            "scene_y_m": float(y - tile.offset[1]),
        }

    def scene_xy(self, scene, x, y):
        """The position in ``scene``'s own frame (its tile's translation taken off), whichever tile
        it lies in; None when the city has no such tile."""
        if self.obj_scene is None or str(scene) not in set(self.obj_scene.tolist()):
            return None
        tile = self._tile(str(scene))
        return None if tile is None else (float(x - tile.offset[0]), float(y - tile.offset[1]))

    def object_place(self, row):
        """The object's scene and its id there (nothing without the city's map)."""
        if self.obj_scene is None:
            return {}
        return {"scene": str(self.obj_scene[row]), "scene_obj_idx": int(self.obj_scene_idx[row])}

    @property
    def geographic(self) -> bool:
        return True

    def framed(self, pts):
        """A city is drawn about the answer alone (the whole map where there is none)."""
        return pts if len(pts) else super().framed(pts)

    def _tile_at(self, xy) -> Tile | None:
        """The tile of the city object nearest ``xy`` (None without the city's lon/lat)."""
        if self.obj_scene is None:
            return None
        _, row = self.index.obj_tree.query(np.asarray(xy, float))
        return self._tile(str(self.obj_scene[int(row)]))

    def _tile(self, scene: str) -> Tile | None:
        """A city tile's frame (its scene's, :func:`flatlandia.geo.frame_for` of its objects, as the
        published scenes') and translation, from its objects' lon/lat and city metres; None when no
        translation fits them (to 1 cm)."""
        if scene not in self.tiles:
            rows = self.obj_scene == scene
            f = geo.frame_for(self.lonlat[rows])
            to_lonlat, to_xy = transformers(f.lon0, f.lat0)
            local = np.column_stack(to_xy.transform(self.lonlat[rows, 0], self.lonlat[rows, 1]))
            offset = np.mean(self.xy[rows] - local, axis=0)
            fits = np.abs(self.xy[rows] - local - offset).max() < 0.01
            self.tiles[scene] = Tile(scene, to_lonlat, to_xy, offset) if fits else None
        return self.tiles[scene]


def _read(path: Path, settings, learned, search) -> CityMap:
    """A city index (one ``.npz`` of ``results/city/{n}/index``), its learned priors (``"auto"``: the
    run's, with the city's map-size correction of the probability) and, beside it, its map's lon/lat."""
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
    m = CityMap(
        path=path,
        obj_idx=ix.obj_id,
        cls=ix.obj_cls,
        xy=ix.obj_xy,
        lonlat=None,
        settings=settings,
        frame=frame,
        index=ix,
        search=search if isinstance(search, city_search.SearchConfig) else city_search.SearchConfig.from_dict(search),
    )
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
        _read_city_table(m, table)
    m.cities = scene_cities(city_dir.parent.parent)
    return m


def _read_city_table(m: CityMap, table: Path) -> None:
    """The city's map beside its index (``results/city/{n}/map.parquet``): each object's lon/lat,
    scene and id there, where it holds every object of the index (else the city has no lon/lat)."""
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
    t = t[t["city"].astype(str) == m.path.stem].set_index("obj_idx")
    if set(t.index) >= set(m.index.obj_id.tolist()):
        t = t.loc[m.index.obj_id]
        m.lonlat = validate.finite_array(t[["lon", "lat"]].to_numpy(float), table, "lon/lat")
        if (np.abs(m.lonlat[:, 0]) > 180).any() or (np.abs(m.lonlat[:, 1]) > 90).any():
            raise InputError(table, "lon/lat must be degrees (lon in [-180, 180], lat in [-90, 90])")
        m.obj_scene = t["scene"].astype(str).to_numpy()
        m.obj_scene_idx = t["scene_obj_idx"].to_numpy(np.int64)
