"""Synthetic cities far larger than the published data: what the search costs at 100,000 objects.

Why synthetic tiles and not more copies: a copy of a published scene holds an exact twin of every
query taken there, which no method can tell apart. A synthetic tile is a published scene (drawn
at random) mirrored, turned by a random angle and with every object moved by a Gaussian jitter:
its class counts, class co-occurrences, spacing and mapping views are those of the published
scenes, but it is no rigid copy of a real place (a mirrored street is the same street only where
it is symmetric, as a real city's repeated streets are). At the 20-scene size, a scene among
synthetic tiles drawn from the *other* scenes is about as hard as among the real ones, while tiles
drawn from the scene itself are harder (measured: docs/measurements.md, "City search"): hence the callers keep
the query's own scene out of the templates.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pandas as pd

from flatlandia.city import tiling


class Template:
    """A published scene as arrays, centred on its bounding box: objects and training views."""

    def __init__(self, ref: pd.DataFrame, queries: pd.DataFrame):
        xy = ref[["x_m", "y_m"]].to_numpy(float)
        self.centre = (xy.min(0) + xy.max(0)) / 2
        self.xy = xy - self.centre
        self.cls = ref["class_id"].to_numpy(np.int64)
        row = {int(o): k for k, o in enumerate(ref["obj_idx"])}
        train = queries[queries["split"] == "train"]
        self.cam = train[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2) - self.centre
        self.heading = np.radians(train["theta_deg"].to_numpy(float))
        self.seen = [np.array([row[int(o)] for o in objs], np.int64) for objs in train["ref_idx"]]


def synthetic_tile(t: Template, rng: np.random.Generator, jitter_m: float):
    """(object xy, view xy, view headings) of one synthetic tile of template ``t``, centred on the
    origin: mirrored, turned by a random angle, objects jittered (views see the same objects)."""
    a = rng.uniform(0, 2 * np.pi)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag([-1.0, 1.0])
    xy = t.xy @ rot.T + rng.normal(0.0, jitter_m, t.xy.shape)
    # a mirrored heading h becomes pi - h, then turns by a
    return xy, t.cam @ rot.T, np.pi - t.heading + a


def city(
    refs: list[pd.DataFrame],
    queries: list[pd.DataFrame],
    templates: list[Template],
    n_objects: int,
    spacing_m: float,
    jitter_m: float,
    rng: np.random.Generator,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(map, queries) of a city of at least ``n_objects``: the published scenes ``refs`` (with all
    their queries) and synthetic tiles of ``templates`` (their training views only, as
    ``split == 'train'`` rows), every tile on a random cell of the grid."""
    picks, total = [], sum(len(r) for r in refs)
    while total < n_objects:
        picks.append(int(rng.integers(len(templates))))
        total += len(templates[picks[-1]].xy)
    offsets = tiling.grid_offsets(len(refs) + len(picks), spacing_m)[rng.permutation(len(refs) + len(picks))]
    ref, q = tiling.place(refs, queries, offsets[: len(refs)])
    objs, views, base = [], [], len(ref)
    for k, off in zip(picks, offsets[len(refs) :]):
        t = templates[k]
        xy, cam, heading = synthetic_tile(t, rng, jitter_m)
        name = f"synthetic-{len(objs)}"
        objs.append(
            pd.DataFrame(
                {
                    "scene": name,
                    "obj_idx": base + np.arange(len(xy)),
                    "class_id": t.cls,
                    "x_m": xy[:, 0] + off[0],
                    "y_m": xy[:, 1] + off[1],
                }
            )
        )
        views.append(
            pd.DataFrame(
                {
                    "scene": name,
                    "split": "train",
                    "x_m": cam[:, 0] + off[0],
                    "y_m": cam[:, 1] + off[1],
                    "theta_deg": np.degrees(heading),
                    "ref_idx": [base + s for s in t.seen],
                }
            )
        )
        base += len(xy)
    return pd.concat([ref] + objs, ignore_index=True), pd.concat([q] + views, ignore_index=True)


def scene_cities(
    scenes: list[str],
    refs: dict[str, pd.DataFrame],
    queries: dict[str, pd.DataFrame],
    n_objects: int,
    spacing_m: float,
    jitter_m: float,
    seed: int,
    split: str,
) -> Iterator[tuple[str, pd.DataFrame, pd.DataFrame]]:
    """(scene, city map, city queries) for each scene that has ``split`` queries, in order: the
    scene among synthetic tiles of the *other* scenes (:func:`city`), ``n_objects`` in all, drawn
    from a generator seeded with (``seed``, the scene's position in ``scenes``). Rule city_simulate's
    cities, which ``benchmarks/bench_city.py`` times."""
    templates = {s: Template(refs[s], queries[s]) for s in scenes}
    for k, s in enumerate(scenes):
        if not (queries[s]["split"] == split).any():
            continue
        rng = np.random.default_rng([int(seed), k])
        others = [templates[t] for t in scenes if t != s]
        ref, q = city([refs[s]], [queries[s]], others, n_objects, float(spacing_m), jitter_m, rng)
        yield s, ref, q
