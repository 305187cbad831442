"""One scene as the query figures and the map viewer see it: reference objects, query cameras,
each query's metric local map at its true pose and at every fine run's estimate.

Why one model for both: the static figures and the interactive page must show the same poses,
matches and errors; they differ only in how they draw them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, vocabulary
from flatlandia.data import localmaps
from flatlandia.data import reference_map as reference_map_module
from flatlandia.plumbing import files
from flatlandia.report.figures import Run

#: the solver's match of each local-map object (reference ``obj_idx``, -1: none), where the run's
#: errors table stores it; without it an estimate's objects are linked to their true positions
MATCH_COLUMN = "matched_obj_idx"
#: the setting whose runs the figures feature and the viewer shows first: (map type, proposal),
#: in order of preference (depth local maps on GT-BB proposals: the paper's realistic case)
FEATURED_SETTINGS = [(t, p) for p in (vocabulary.GTBB, vocabulary.WHOLE) for t in ("depth", "gt")]


@dataclass(frozen=True)
class Estimate:
    """One run's pose of one query and its errors (NaN pose: the run gave none)."""

    run: Run
    x: float
    y: float
    theta_deg: float
    error_m: float
    error_deg: float
    n_inliers: int
    n_correct_inliers: int
    matches: tuple[int, ...] | None

    @property
    def has_pose(self) -> bool:
        return bool(np.isfinite([self.x, self.y, self.theta_deg]).all())

    def place(self, local: np.ndarray) -> np.ndarray:
        """The local map (camera frame, metres) laid on the map at this pose."""
        return geo.local_to_world(local, (self.x, self.y), np.radians(self.theta_deg))

    def summary(self) -> str:
        """The errors as the figures write them."""
        if not self.has_pose:
            return "no pose"
        text = f"{self.error_m:.2f} m, {self.error_deg:.1f}°"
        if self.run.method in vocabulary.SOLVER_METHODS:
            text += f" ({self.n_inliers} inliers, {self.n_correct_inliers} correct)"
        return text


@dataclass(frozen=True)
class QueryView:
    """A query: its true camera, its GT local map (metres) with the reference ``obj_idx`` of each
    object, and the runs' estimates (test queries only)."""

    token: str
    split: str
    x: float
    y: float
    theta_deg: float
    ref_idx: tuple[int, ...]
    local: np.ndarray
    estimates: tuple[Estimate, ...]

    def truth(self) -> np.ndarray:
        """The local map at the true pose: on its reference objects, up to recovery's residual."""
        return geo.local_to_world(self.local, (self.x, self.y), np.radians(self.theta_deg))

    def estimate(self, run: str) -> Estimate | None:
        return next((e for e in self.estimates if e.run.name == run), None)


@dataclass(frozen=True)
class SceneView:
    scene: str
    axes: tuple[str, str]
    ref: pd.DataFrame
    queries: tuple[QueryView, ...]
    runs: tuple[Run, ...]
    featured: tuple[str, ...]

    def test_queries(self) -> list[QueryView]:
        return [q for q in self.queries if q.split == "test"]

    def object_xy(self, obj_idx) -> np.ndarray:
        """Map positions of reference objects by ``obj_idx`` (NaN for an unknown index)."""
        pos = dict(zip(self.ref["obj_idx"].astype(int), self.ref[["x_m", "y_m"]].to_numpy(float)))
        return np.array([pos.get(int(o), (np.nan, np.nan)) for o in obj_idx], float).reshape(-1, 2)


def featured_runs(errors: dict[str, pd.DataFrame]) -> tuple[str, ...]:
    """The solver's run and the best learned run (lowest median position error over all its test
    queries) of one setting: the first of FEATURED_SETTINGS, then of the others, that has a solver
    run (any built-in run, where no setting has one); then one run of each external method (config
    ``external``: the runs of one's own poses are what its author looks for), of that setting where
    it has one, else its first in the same order of settings."""
    runs = [Run.parse(name) for name in errors]
    builtin = [r for r in runs if not r.external]
    has_solver = any(r.method == "solver" for r in builtin)
    settings = FEATURED_SETTINGS + sorted({(r.map_type, r.proposal) for r in runs} - set(FEATURED_SETTINGS))
    featured, chosen = [], None
    for map_type, proposal in settings:
        same = [r for r in builtin if (r.map_type, r.proposal) == (map_type, proposal)]
        solver = [r.name for r in same if r.method == "solver"]
        learned = sorted(
            (float(np.median(errors[r.name]["error_m"])), r.name)
            for r in same
            if r.method not in vocabulary.SOLVER_METHODS
        )
        if solver or (learned and not has_solver):
            featured, chosen = solver[:1] + [name for _, name in learned[:1]], (map_type, proposal)
            break
    order = ([chosen] if chosen else []) + settings
    for method in sorted({r.method for r in runs if r.external}):
        mine = {(r.map_type, r.proposal): r.name for r in runs if r.method == method}
        featured.append(next(mine[s] for s in order if s in mine))
    return tuple(featured)


def _estimate(run: Run, row) -> Estimate:
    """A run's row; its matches only where it stores one per local-map object (learned runs: none)."""
    matches = getattr(row, MATCH_COLUMN, None)
    if matches is not None and len(matches) != int(row.n_objects):
        matches = None
    return Estimate(
        run=run,
        x=float(row.x),
        y=float(row.y),
        theta_deg=float(row.theta_deg),
        error_m=float(row.error_m),
        error_deg=float(row.error_deg),
        n_inliers=int(row.n_inliers),
        n_correct_inliers=int(row.n_correct_inliers),
        matches=None if matches is None else tuple(int(m) for m in matches),
    )


def scene_view(
    scene: str,
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    errors: dict[str, pd.DataFrame],
    axes: tuple[str, str] = ("x east (m)", "y north (m)"),
) -> SceneView:
    """The scene's model; ``errors`` maps run names to their errors tables (every scene's rows:
    this scene's are taken), empty for a scene no run localizes."""
    runs = tuple(sorted((Run.parse(name) for name in errors), key=Run.sort_key))
    rows = {}
    for run in runs:
        e = errors[run.name]
        for row in e[e["scene"].astype(str) == str(scene)].itertuples(index=False):
            rows.setdefault(str(row.token), []).append(_estimate(run, row))
    views = tuple(
        QueryView(
            token=str(q.token),
            split=str(q.split),
            x=float(q.x_m),
            y=float(q.y_m),
            theta_deg=float(q.theta_deg),
            ref_idx=tuple(int(o) for o in q.ref_idx),
            local=localmaps.local_map(q, "gt"),
            estimates=tuple(rows.get(str(q.token), [])),
        )
        for q in queries.sort_values("token", kind="stable").itertuples(index=False)
    )
    return SceneView(str(scene), tuple(axes), ref.reset_index(drop=True), views, runs, featured_runs(errors))


def read_view(scene: str, reference_map: str | Path, queries: str | Path, errors: dict[str, str | Path]) -> SceneView:
    """The scene's model from its files: a rule's inputs, ``errors`` by run name."""
    axes = reference_map_module.axis_labels(files.read_parquet_metadata(reference_map))
    tables = {run: pd.read_parquet(path) for run, path in errors.items()}
    return scene_view(scene, pd.read_parquet(reference_map), pd.read_parquet(queries), tables, axes)


def worst_queries(view: SceneView, n: int) -> list[QueryView]:
    """The ``n`` test queries the first featured run localizes worst: no pose first, then by
    position error, then heading error (token breaks ties)."""
    if not view.featured:
        return []

    def key(q: QueryView):
        e = q.estimate(view.featured[0])
        m = float("inf") if e is None or not np.isfinite(e.error_m) else e.error_m
        d = 180.0 if e is None or not np.isfinite(e.error_deg) else e.error_deg
        return (-m, -d, q.token)

    return sorted(view.test_queries(), key=key)[:n]
