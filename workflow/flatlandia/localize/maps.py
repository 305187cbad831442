"""The reader of the maps a query is localized on: :func:`load_map` reads a file once, for many
queries, and picks its kind there, the one place a kind is chosen (:data:`KINDS`).

A kind is a class of :mod:`flatlandia.localize.object_map`'s :class:`ObjectMap`: a scene's
reference map (:class:`~flatlandia.localize.scene_map.SceneMap`: the workflow's, or any GeoParquet /
GeoJSON of classed points, with the solver's priors a workflow run gives it) or a city index
(:class:`~flatlandia.localize.city_map.CityMap`: with its map's lon/lat, each tile in its scene's
frame). Adding a kind is its class (a module of its own) and its line in :data:`KINDS`; the
localizer calls the class's methods and never asks which kind a map is.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from flatlandia import vocabulary
from flatlandia.localize.city_map import CityMap, Tile
from flatlandia.localize.object_map import ObjectMap, metres_to_map, scene_cities
from flatlandia.localize.scene_map import SceneMap, pd_frame, read_training, set_training_priors
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

# the solver loads numba (seconds; docs/measurements.md, "Start-up costs"): only a loaded map needs it
if TYPE_CHECKING:
    from flatlandia import solver
    from flatlandia.city.search import SearchConfig

MAP_TYPES = vocabulary.MAP_TYPES

#: the kinds of map, in the order a file is offered to them: the first whose ``suffixes`` hold the
#: file's reads it (a folder: the one city index it holds)
KINDS: tuple[type[ObjectMap], ...] = (SceneMap, CityMap)

__all__ = [
    "KINDS",
    "MAP_TYPES",
    "CityMap",
    "ObjectMap",
    "SceneMap",
    "Tile",
    "load_map",
    "metres_to_map",
    "pd_frame",
    "place",
    "read_training",
    "scene_cities",
    "scene_xy",
    "set_training_priors",
]


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
    kind = next((k for k in KINDS if path.suffix.lower() in k.suffixes), None)
    if kind is None:
        raise InputError(path, f"not a map: expected {' or '.join(k.described for k in KINDS)}")
    m = kind.read(path, settings, learned, search)
    solver.warm_up()
    return m


def place(m: ObjectMap, x: float, y: float) -> dict:
    """Which scene (and city) a pose at (x, y) of the map's frame lies in, as JSON values
    (:meth:`ObjectMap.place`: a city's with the pose in its scene's own frame)."""
    return m.place(x, y)


def scene_xy(m: ObjectMap, scene: str, x: float, y: float) -> tuple[float, float] | None:
    """A position of the map's frame in ``scene``'s own frame (:meth:`ObjectMap.scene_xy`); None
    when a city has no such tile. On a scene map, the position as given."""
    return m.scene_xy(scene, x, y)
