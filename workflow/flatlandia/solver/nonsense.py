"""Queries that fit no place of a map: what the null hypothesis is calibrated against.

Why: the answers' calibration learned on validation queries only, and every one of them has a true
place, so a query that fits nowhere (a user's wrong map, a detector's hallucinations) came back
`ok` about one time in ten (docs/results.md, "Know when it is right"). Three kinds, each built from
a real query of the split so that its size and its classes look real:

- ``random_places``: the query's own classes at random places in view;
- ``random_classes``: 3-6 classes drawn from the map's own mix, at random places in view;
- ``other_scene``: the query itself, asked of another scene's map.

Places in view: bearings uniform within the field of view, ranges log-uniform over a factor of
e either side of 1, normalised to a median range of 1 (a depth local map's units), or, for GT local
maps (metres), to the median range of the real query it is drawn from.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: the kinds of nonsense query, in the order they are drawn
KINDS = ("random_places", "random_classes", "other_scene")
#: half the field of view of the random places (degrees): the depth maps' (the likelihood model's
#: fitted field of view is about 55 degrees)
FOV_HALF_DEG = 50.0


class Nonsense(NamedTuple):
    """One nonsense query: asked of the map of scene ``scene`` (an index into the scenes given)."""

    scene: int
    kind: str
    xy: np.ndarray  # (M, 2) depth local map, camera at the origin looking along +x
    classes: np.ndarray  # (M,)


def random_layout(rng: np.random.Generator, n: int, fov_half_deg: float = FOV_HALF_DEG) -> np.ndarray:
    """(n, 2) objects at random places in view, median range 1."""
    bearing = np.radians(rng.uniform(-fov_half_deg, fov_half_deg, n))
    rng_ = np.exp(rng.uniform(-1.0, 1.0, n))
    rng_ = rng_ / np.median(rng_)
    return np.column_stack([rng_ * np.cos(bearing), rng_ * np.sin(bearing)])


def draw(
    queries: list[tuple[np.ndarray, np.ndarray]],
    map_classes: list[np.ndarray],
    seed: int,
    kinds: tuple[str, ...] = KINDS,
    metric: bool = False,
) -> list[Nonsense]:
    """One nonsense query per real query and kind: ``queries[i]`` are scene ``i``'s real queries as
        (depth local map, classes), ``map_classes[i]`` the class of each object of scene ``i``'s map;
        ``other_scene`` asks scene ``i``'s queries of scene ``i + 1``'s map (needs two scenes); ``metric``:
    the queries are GT local maps (metres), and the random places take each real query's median range.
    Seeded."""
    rng = np.random.default_rng(seed)
    out = []
    n_scenes = len(map_classes)
    for i, scene_queries in enumerate(queries):
        for xy, cls in scene_queries:
            cls = np.asarray(cls, int)
            unit = float(np.median(np.hypot(*np.asarray(xy, float).T))) if metric else 1.0
            for kind in kinds:
                if kind == "random_places":
                    out.append(Nonsense(i, kind, unit * random_layout(rng, len(cls)), rng.permutation(cls)))
                elif kind == "random_classes" and len(map_classes[i]):
                    n = int(rng.integers(3, 7))
                    out.append(Nonsense(i, kind, unit * random_layout(rng, n), rng.choice(map_classes[i], n)))
                elif kind == "other_scene" and n_scenes > 1:
                    out.append(Nonsense((i + 1) % n_scenes, kind, np.asarray(xy, float), cls))
    return out
