"""A scene written as a city of one tile (the tests of the city index as a map, a batch, a broken
city): the tile moved 3 km east and 2 km south, ``map.parquet`` and ``index/0.npz`` as rule
city_index writes them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.city import index, tiling
from flatlandia.plumbing import files

#: where the one tile lies in the city's frame (metres east, north)
OFFSET = np.array([[3000.0, -2000.0]])


def write_one_tile_city(
    ref: pd.DataFrame, queries: pd.DataFrame, city: Path, edit=None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the city's map, its queries) of the scene ``ref``, ``queries`` written under ``city``;
    ``edit(map)`` changes the city's map before it is written and indexed (a broken input)."""
    cref, cq = tiling.place([ref], [queries], OFFSET)
    cref = cref.drop(columns=["geometry"], errors="ignore").assign(city=0)
    if edit is not None:
        cref = edit(cref)
    (city / "index").mkdir(parents=True, exist_ok=True)
    files.write_parquet(cref, city / "map.parquet")
    index.build(cref, cq[cq["split"] == "train"]).save(city / "index" / "0.npz")
    return cref, cq
