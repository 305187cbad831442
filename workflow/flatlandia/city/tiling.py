"""A simulated city: published scenes tiled on a grid into one reference map.

Why: a real city's object map holds tens of thousands of objects and a user does not know the
scene; the published scenes are 13-290 objects each. Tiling them keeps every scene's geometry
(a pure translation per scene), makes object ids unique, and carries each scene's queries and
training cameras along, so the solver's priors and the ground truth stay valid in the city frame.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd


def grid_offsets(n: int, spacing_m: float) -> np.ndarray:
    """(n, 2) offsets of n tiles, row by row on a square-ish grid ``spacing_m`` apart."""
    cols = max(1, math.ceil(math.sqrt(n)))
    k = np.arange(n)
    return np.column_stack([k % cols, k // cols]).astype(float) * float(spacing_m)


def tile(refs: list[pd.DataFrame], queries: list[pd.DataFrame], spacing_m: float) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(city reference map, city queries) of scenes given in tile order, on the grid."""
    return place(refs, queries, grid_offsets(len(refs), spacing_m))


def place(
    refs: list[pd.DataFrame], queries: list[pd.DataFrame], offsets: np.ndarray
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(city reference map, city queries) of scenes moved by ``offsets`` (n, 2).

    The map keeps each scene's columns, moves ``x_m, y_m`` by the scene's offset and renumbers
    ``obj_idx`` 0..N-1 (the scene's own id stays in ``scene_obj_idx``). Queries move alike
    (``x_m, y_m``; local maps and headings are in the camera frame and do not change) and their
    ``ref_idx`` point to the city ids, so ``solver.priors.training_priors`` works on the city table.
    """
    maps, qs, base = [], [], 0
    for (dx, dy), ref, q in zip(np.asarray(offsets, float), refs, queries):
        ref = ref.copy()
        city_id = {int(o): base + k for k, o in enumerate(ref["obj_idx"])}
        ref["scene_obj_idx"] = ref["obj_idx"].astype(int)
        ref["obj_idx"] = np.arange(base, base + len(ref))
        ref["x_m"] = ref["x_m"] + dx
        ref["y_m"] = ref["y_m"] + dy
        q = q.copy()
        q["x_m"] = q["x_m"] + dx
        q["y_m"] = q["y_m"] + dy
        q["ref_idx"] = [[city_id[int(o)] for o in r] for r in q["ref_idx"]]
        maps.append(ref)
        qs.append(q)
        base += len(ref)
    return pd.concat(maps, ignore_index=True), pd.concat(qs, ignore_index=True)


def groups(scenes: list[str], per_city: int) -> list[list[str]]:
    """The scenes cut into consecutive cities of ``per_city`` scenes (the last may be smaller), so
    that every scene's queries are localized in a city of that size."""
    return [scenes[i : i + per_city] for i in range(0, len(scenes), per_city)]
