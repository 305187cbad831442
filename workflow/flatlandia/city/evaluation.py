"""Errors of a city's queries under the two methods, and their summary row.

``solver``: today's geometric solver on the whole city map (every object a candidate, every view
a prior), through ``benchmark.solver_runs.evaluate_solver``. ``index``: the city search
(:mod:`flatlandia.city.search`). Both rows share ``benchmark.metrics.error_row``'s columns; the
index adds whether the true place was among its regions (``region_hit``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from flatlandia import geo, proposals, solver
from flatlandia.benchmark import metrics, solver_runs
from flatlandia.city import index, search, simulate
from flatlandia.city.index import ViewIndex
from flatlandia.data import localmaps

#: a pose farther than this from the truth is in the wrong scene (scenes are < 300 m across and
#: tiled 1 km apart)
WRONG_SCENE_M = metrics.WRONG_SCENE_M


def solver_errors(
    ref: pd.DataFrame, queries: pd.DataFrame, split: str, settings: dict, learned: solver.LearnedPriors | None
) -> pd.DataFrame:
    """Today's solver on the whole map of one city: the ``split`` queries, priors from its training split."""
    test = queries[queries["split"] == split]
    return solver_runs.evaluate_solver(
        ref,
        test,
        proposals.whole_map_proposals(ref, test),
        "depth",
        settings,
        priors=solver.scene_priors(ref, queries, settings, learned),
        method="whole-map solver",
    )


def index_errors(
    ix: ViewIndex,
    queries: pd.DataFrame,
    split: str,
    cfg: search.SearchConfig,
    settings: dict,
    learned: solver.LearnedPriors | None,
) -> pd.DataFrame:
    """The city search on the ``split`` queries of one city (the index holds its training views)."""
    solver_settings = solver.SolverConfig.from_dict(settings)
    solver.warm_up()
    rows = []
    for r in queries[queries["split"] == split].itertuples(index=False):
        q = localmaps.local_map(r, "depth")
        t0, c0 = time.perf_counter(), time.process_time()
        found = search.search_city(ix, q, np.asarray(r.classes), cfg, solver_settings, learned)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        sol = found.solution
        if sol is None:
            pose, errors, fit = (np.nan, np.nan, np.nan), (np.inf, 180.0), (0.0, 0, 0)
        else:
            pose = (sol.x, sol.y, sol.theta)
            errors = geo.pose_errors(sol.x, sol.y, sol.theta, r.x_m, r.y_m, np.radians(r.theta_deg))
            truth = [int(o) for o in r.ref_idx]
            correct = sum(int(ix.obj_id[found.rows[c]]) == truth[k] for k, c in sol.inliers)
            fit = (sol.confidence, len(sol.inliers), correct)
        row = metrics.error_row(
            r,
            method="index + solver",
            map_type="depth",
            strategy="city index",
            proposal_classes=ix.obj_cls[found.rows],
            lat=float(r.lat),
            pose=pose,
            errors=errors,
            fit=fit,
            seconds=dt,
            cpu_seconds=dc,
            probability=sol.probability if sol is not None else 0.0,
            answered=metrics.answered(sol, solver_settings),
        )
        near = np.hypot(*(found.centres - [r.x_m, r.y_m]).T) if len(found.centres) else np.zeros(0)
        row["region_hit"] = bool(np.any(near <= cfg.nms_m))
        rows.append(row)
    return pd.DataFrame(rows)


def summary(errors: pd.DataFrame) -> dict:
    """The table's figures of one method at one city size (``benchmark.metrics.summarise`` plus the
    city's own: within (5 m, 5 deg), wrong scene, CPU p90, region hits; the answers' figures,
    ``benchmark.metrics.answer_summary``)."""
    s = metrics.summarise(errors)
    em, ed = errors["error_m"].to_numpy(float), errors["error_deg"].to_numpy(float)
    cpu = errors["cpu_seconds"].to_numpy(float)
    out = {
        k: s[k]
        for k in [
            "queries",
            "median_m",
            "median_deg",
            *metrics.RECALL_COLUMNS,
            "no_pose_pct",
            *metrics.ANSWER_COLUMNS,
        ]
    }
    out.update(
        within_5m_5deg=float(100 * np.mean((em < 5) & (ed < 5))),
        wrong_scene_pct=float(100 * np.mean(np.isfinite(em) & (em > WRONG_SCENE_M))),
        cpu_median_ms=float(1000 * np.median(cpu)),
        cpu_p90_ms=float(1000 * np.percentile(cpu, 90)),
        region_hit_pct=float(100 * errors["region_hit"].mean()) if "region_hit" in errors else float("nan"),
    )
    return out


# --------------------------------------------------------------------------- rules city_eval, city_simulate


def tiled_errors(
    maps: pd.DataFrame,
    queries: pd.DataFrame,
    scenes_per_city: int,
    method: str,
    split: str,
    cfg: search.SearchConfig,
    settings: dict,
    learned: solver.LearnedPriors | None,
    index_of: Callable[[str], ViewIndex] | None = None,
    built: list[dict] | None = None,
    log=None,
) -> tuple[pd.DataFrame, dict]:
    """Rule city_eval: one method on every city of the tiled maps -> (per-query errors, summary row).

    ``maps``/``queries``: the tiled cities of ``scenes_per_city`` scenes (rule city_maps, column
    ``city``); ``method`` ``solver``
    (today's solver on each whole city map, :func:`solver_errors`) or ``index`` (the city search,
    :func:`index_errors`, with ``index_of(city)`` the city's saved index and ``built`` rule city_index's
    build records: bytes and CPU seconds per city)."""
    parts = []
    for city, ref in maps.groupby("city", sort=True):
        q = queries[queries["city"] == city]
        if method == "solver":
            parts.append(solver_errors(ref, q, split, settings, learned))
        else:
            parts.append(index_errors(index_of(city), q, split, cfg, settings, learned))
        if log is not None:
            log.info("city %s: %s", city, summary(parts[-1]) if len(parts[-1]) else "no queries")
    built = built or []
    errors = pd.concat(parts, ignore_index=True)
    out = summary(errors)
    out.update(
        map="tiled",
        scenes=int(scenes_per_city),
        cities=int(maps["city"].nunique()),
        objects=int(round(maps.groupby("city").size().mean())),
        method=str(errors["method"].iloc[0]),
        index_mb=float(np.mean([b["bytes"] for b in built]) / 1e6) if built else float("nan"),
        index_build_s=float(np.mean([b["cpu_s"] for b in built])) if built else float("nan"),
    )
    return errors, out


def simulated_errors(
    scenes: list[str],
    refs: dict[str, pd.DataFrame],
    queries: dict[str, pd.DataFrame],
    n_objects: int,
    spacing_m: float,
    simulate_cfg: dict,
    seed: int,
    split: str,
    cfg: search.SearchConfig,
    settings: dict,
    learned: solver.LearnedPriors | None,
    log=None,
) -> tuple[pd.DataFrame, dict]:
    """Rule city_simulate: the city search in synthetic cities of ``n_objects`` objects ->
    (per-query errors, summary row). Each scene's ``split`` queries are localized in its city
    (:func:`flatlandia.city.simulate.scene_cities`), indexed from the city's training views as rule
    city_index does (build CPU seconds and size averaged into the summary)."""
    parts, built, sizes, tiles = [], [], [], []
    cities = simulate.scene_cities(scenes, refs, queries, n_objects, spacing_m, simulate_cfg["jitter_m"], seed, split)
    for s, ref, q in cities:
        c0 = time.process_time()
        ix = index.build(ref, q[q["split"] == "train"])
        built.append((ix.nbytes(), time.process_time() - c0))
        sizes.append(len(ref))
        tiles.append(ref["scene"].nunique())
        parts.append(index_errors(ix, q[q["scene"] == s], split, cfg, settings, learned))
        if log is not None:
            log.info("scene %s: %d objects, %s", s, len(ref), summary(parts[-1]))
    errors = pd.concat(parts, ignore_index=True)
    out = summary(errors)
    out.update(
        map="simulated",
        scenes=int(round(np.mean(tiles))),
        cities=len(parts),
        objects=int(round(np.mean(sizes))),
        method=str(errors["method"].iloc[0]),
        index_mb=float(np.mean([b for b, _ in built]) / 1e6),
        index_build_s=float(np.mean([c for _, c in built])),
    )
    return errors, out
