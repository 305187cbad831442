"""Errors of the anchors of "beyond one frame" (:mod:`flatlandia.sequences.protocol`) and their summaries.

Rows are anchors (test queries) under one setting: the map (a scene's whole map, the tiled city of
20 scenes, or a simulated city), the frames used (the anchor and its nearest companions), the GPS
sigma of the anchor's simulated fix (None: no fix) and the camera prior (the scene's training
cameras, less the companions; or none at all). Each row holds the anchor's errors, how many of the
sequence's frames came out within (5 m, 5 deg) (the second figure: every frame), the CPU of the
whole sequence, whether the pose is in the wrong scene, and the true-match bound of the same
sequence (:func:`flatlandia.solver.sequence.true_match_poses`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from flatlandia import geo, solver
from flatlandia.benchmark import metrics
from flatlandia.city import index as city_index
from flatlandia.city import search, simulate
from flatlandia.data import localmaps
from flatlandia.sequences import protocol
from flatlandia.solver.sequence import SequenceConfig, true_match_poses

#: a pose farther than this from the truth is in the wrong scene (flatlandia.city.evaluation)
WRONG_SCENE_M = metrics.WRONG_SCENE_M
#: (5 m, 5 deg): the share a user would call localized
WITHIN_M, WITHIN_DEG = metrics.WITHIN


@dataclass(frozen=True)
class Setting:
    """One row's setting: frames (the anchor and frames-1 companions), the fix's sigma (None: no
    fix), the camera prior on or off."""

    frames: int
    gps_sigma_m: float | None = None
    camera_prior: bool = True


def settings_grid(beyond: dict, camera_prior: bool) -> list[Setting]:
    """The table's settings from the config section ``beyond``: every frame count without a fix
    and, with the camera prior on, each GPS sigma at each of ``gps_frames`` (the rows without the
    camera prior say how much it carries; a fix does not change that)."""
    out = [Setting(int(k), None, bool(camera_prior)) for k in beyond["frames"]]
    if camera_prior:
        out += [Setting(int(k), float(g), True) for k in beyond["gps_frames"] for g in beyond["gps_sigmas_m"]]
    return list(dict.fromkeys(out))


@dataclass
class Anchor:
    """One anchor and its sequence: the frames' local maps, true poses, tokens, the simulated
    odometry of the whole chain and the GPS draw."""

    scene: str
    token: str
    frames: list  # [(xy, classes)], anchor first, chain order
    truth: np.ndarray  # (F, 3)
    tokens: list[str]
    matched: list  # per frame, the reference obj_idx of each object (the true matches)
    scales: np.ndarray  # (F,) the depth maps' oracle scales (the bound's start)
    odo: protocol.Odometry
    draw: np.ndarray  # (2,) the GPS draw


def anchors(queries: pd.DataFrame, split: str, beyond: dict, seed: int, candidates: pd.DataFrame | None = None):
    """The anchors of one scene's ``split`` queries (:func:`flatlandia.sequences.protocol.sequence_rows`:
    companions among ``candidates``, default ``queries``, which must hold the anchors)."""
    pool = queries if candidates is None else candidates
    pool = pool.reset_index(drop=True)
    companions = max(int(k) for k in beyond["frames"] + beyond["gps_frames"]) - 1
    truth_all = protocol.poses(pool)
    out = []
    for rows in protocol.sequence_rows(pool, split, companions, float(beyond["sequence_radius_m"])):
        sub = pool.iloc[rows]
        r0 = sub.iloc[0]
        truth = truth_all[rows]
        out.append(
            Anchor(
                str(r0["scene"]),
                str(r0["token"]),
                [(localmaps.local_map(r, "depth"), np.asarray(r.classes)) for r in sub.itertuples(index=False)],
                truth,
                sub["token"].astype(str).tolist(),
                [np.asarray(v, np.int64) for v in sub["ref_idx"]],
                sub["depth_oracle_scale_m"].to_numpy(float),
                protocol.odometry(
                    truth,
                    protocol.rng_for(seed, protocol.ODOMETRY, r0["scene"], r0["token"]),
                    float(beyond["odometry_distance_pct"]),
                    float(beyond["odometry_heading_deg"]),
                ),
                protocol.gps_draw(seed, str(r0["scene"]), str(r0["token"])),
            )
        )
    return out


def _fix(a: Anchor, s: Setting):
    return protocol.gps_fix(a.truth[0, :2], a.draw, s.gps_sigma_m) if s.gps_sigma_m is not None else None


def _row(a: Anchor, s: Setting, k: int, found, cpu: float, wall: float, bound, map_name: str, threshold: float) -> dict:
    """One anchor's row: its errors, every frame's, the CPU, the bound and its answer (probability,
    answered at ``threshold``: ``solver.answer_probability``)."""
    b = found.best
    if b is None:
        e_m, e_deg, within = np.inf, 180.0, 0
        pose = (np.nan, np.nan, np.nan)
    else:
        e_m, e_deg = geo.pose_errors(b.x, b.y, b.theta, *a.truth[0])
        pose = (b.x, b.y, b.theta)
        fe = [geo.pose_errors(p.x, p.y, p.theta, *a.truth[f]) for f, p in enumerate(found.frames[:k])]
        within = int(sum((m < WITHIN_M) and (d < WITHIN_DEG) for m, d in fe))
    be_m, be_deg = geo.pose_errors(bound[0].x, bound[0].y, bound[0].theta, *a.truth[0])
    b_within = int(
        sum(
            (m < WITHIN_M) and (d < WITHIN_DEG)
            for m, d in (geo.pose_errors(p.x, p.y, p.theta, *a.truth[f]) for f, p in enumerate(bound))
        )
    )
    return {
        "map": map_name,
        "scene": a.scene,
        "token": a.token,
        "frames": int(s.frames),
        "frames_used": int(k),
        "gps_sigma_m": float(s.gps_sigma_m) if s.gps_sigma_m is not None else float("nan"),
        "camera_prior": "on" if s.camera_prior else "off",
        "n_objects": int(len(a.frames[0][0])),
        "x": float(pose[0]),
        "y": float(pose[1]),
        "theta_deg": float(np.degrees(pose[2])) if np.isfinite(pose[2]) else float("nan"),
        "error_m": float(e_m),
        "error_deg": float(e_deg),
        "frames_within": within,
        "bound_error_m": float(be_m),
        "bound_error_deg": float(be_deg),
        "bound_frames_within": b_within,
        "cpu_seconds": float(cpu),
        "seconds": float(wall),
        "solvable": True,
        "confidence": float(b.confidence) if b is not None else 0.0,
        "probability": float(b.probability) if b is not None else 0.0,
        "agreement": float(b.agreement) if b is not None and b.agreement is not None else float("nan"),
        "answered": bool(b is not None and not b.probability < threshold),
    }


def _bound(a: Anchor, s: Setting, k: int, ref_xy_of: Callable, cfg, cache: dict):
    """The true-match bound of the anchor's first ``k`` frames under the setting's fix (cached per
    (k, sigma): the camera prior does not enter it)."""
    key = (k, s.gps_sigma_m)
    if key not in cache:
        cache[key] = true_match_poses(
            a.frames[:k],
            a.odo.rel[:k],
            [ref_xy_of(m) for m in a.matched[:k]],
            a.truth[0],
            a.scales[:k],
            cfg,
            a.odo.sigma[:k],
            _fix(a, s),
        )
    return cache[key]


def scene_errors(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: list[Setting],
    solver_settings: dict,
    beyond: dict,
    learned: solver.LearnedPriors | None,
    seed: int,
    split: str = "test",
    every: int = 1,
    log=None,
) -> pd.DataFrame:
    """Rule beyond_scene: every anchor of each scene (reference map, queries) on its scene's whole
    map under every setting (every ``every``-th anchor: a subset for tuning)."""
    cfg = solver.SolverConfig.from_dict(solver_settings)
    seq = SequenceConfig.from_dict(beyond["sequence"])
    solver.warm_up()
    warm_up_sequence()
    rows = []
    for ref, q in scenes:
        ref_xy, ref_cls = ref[["x_m", "y_m"]].to_numpy(float), ref["class_id"].to_numpy()
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"])}
        full = solver.scene_priors(ref, q, solver_settings, learned)
        off = solver.with_learned(solver.TrainingPriors(), learned)
        for a in anchors(q, split, beyond, seed)[::every]:
            cache: dict = {}
            for s in settings:
                k = min(s.frames, len(a.frames))
                given = protocol.leave_out(full, q, a.tokens[1:k]) if s.camera_prior else off
                t0, c0 = time.perf_counter(), time.process_time()
                found = solver.locate_sequence(
                    a.frames[:k], a.odo.rel[:k], ref_xy, ref_cls, cfg, given, seq, a.odo.sigma[:k], _fix(a, s)
                )
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                bound = _bound(a, s, k, lambda m, xy=ref_xy, pos=pos: xy[[pos[int(o)] for o in m]], cfg, cache)
                rows.append(_row(a, s, k, found, cpu, wall, bound, "scene", cfg.answer_probability))
        if log is not None and len(ref):
            log.info("scene %s: %d rows so far", ref["scene"].iloc[0], len(rows))
    return pd.DataFrame(rows)


def _view_rows(views: pd.DataFrame) -> dict[str, int]:
    """token -> row of the index's views (built from ``views`` in order: the training split)."""
    return {str(t): k for k, t in enumerate(views["token"].astype(str))}


def city_anchor_errors(
    ix: city_index.ViewIndex,
    views: pd.DataFrame,
    anchors_: list[Anchor],
    settings: list[Setting],
    ref_xy_of: Callable,
    cfg: search.SearchConfig,
    solver_cfg: solver.SolverConfig,
    seq: SequenceConfig,
    learned: solver.LearnedPriors | None,
    map_name: str,
) -> list[dict]:
    """The city search on a sequence per anchor under every setting (camera prior on: the index's
    views less the companions')."""
    view_of = _view_rows(views)
    rows = []
    for a in anchors_:
        cache: dict = {}
        for s in settings:
            k = min(s.frames, len(a.frames))
            exclude = np.array([view_of[t] for t in a.tokens[1:k] if t in view_of], np.int64)
            t0, c0 = time.perf_counter(), time.process_time()
            found, _ = search.search_city_sequence(
                ix,
                a.frames[:k],
                a.odo.rel[:k],
                cfg,
                solver_cfg,
                seq,
                learned,
                a.odo.sigma[:k],
                _fix(a, s),
                exclude,
            )
            cpu, wall = time.process_time() - c0, time.perf_counter() - t0
            bound = _bound(a, s, k, ref_xy_of, solver_cfg, cache)
            rows.append(_row(a, s, k, found, cpu, wall, bound, map_name, solver_cfg.answer_probability))
    return rows


def tiled_city_errors(
    maps: pd.DataFrame,
    queries: pd.DataFrame,
    index_of: Callable[[str], city_index.ViewIndex],
    settings: list[Setting],
    solver_settings: dict,
    search_settings: dict,
    beyond: dict,
    learned: solver.LearnedPriors | None,
    seed: int,
    split: str = "test",
    map_name: str = "city-20",
    every: int = 1,
    log=None,
) -> pd.DataFrame:
    """Rule beyond_city on a tiled city (rule city_maps' map and queries, rule city_index's index
    per city): every anchor's sequence searched in its city."""
    cfg = search.SearchConfig.from_dict(search_settings)
    solver_cfg = solver.SolverConfig.from_dict(solver_settings)
    seq = SequenceConfig.from_dict(beyond["sequence"])
    solver.warm_up()
    warm_up_sequence()
    rows = []
    for city, ref in maps.groupby("city", sort=True):
        q = queries[queries["city"] == city]
        ix = index_of(str(city))
        xy = dict(zip(ref["obj_idx"].astype(int), ref[["x_m", "y_m"]].to_numpy(float)))
        found = []
        for _, qs in q.groupby("scene", sort=False):
            found += anchors(qs, split, beyond, seed)[::every]
        rows += city_anchor_errors(
            ix,
            q[q["split"] == "train"],
            found,
            settings,
            lambda m, xy=xy: np.array([xy[int(o)] for o in m]).reshape(-1, 2),
            cfg,
            solver_cfg,
            seq,
            learned,
            map_name,
        )
        if log is not None:
            log.info("city %s: %d rows", city, len(rows))
    return pd.DataFrame(rows)


def simulated_city_errors(
    scenes: list[str],
    refs: dict[str, pd.DataFrame],
    queries: dict[str, pd.DataFrame],
    n_objects: int,
    simulate_cfg: dict,
    spacing_m: float,
    settings: list[Setting],
    solver_settings: dict,
    search_settings: dict,
    beyond: dict,
    learned: solver.LearnedPriors | None,
    seed: int,
    split: str = "test",
    every: int = 1,
    log=None,
) -> pd.DataFrame:
    """Rule beyond_city on simulated cities: each scene among synthetic tiles of the other scenes,
    the very cities of rule city_simulate (:func:`flatlandia.city.simulate.scene_cities`, same seed),
    indexed as there; every anchor's sequence searched in its scene's city."""
    cfg = search.SearchConfig.from_dict(search_settings)
    solver_cfg = solver.SolverConfig.from_dict(solver_settings)
    seq = SequenceConfig.from_dict(beyond["sequence"])
    solver.warm_up()
    warm_up_sequence()
    rows, sizes = [], []
    cities = simulate.scene_cities(scenes, refs, queries, n_objects, spacing_m, simulate_cfg["jitter_m"], seed, split)
    for s, ref, q in cities:
        sizes.append(len(ref))
        views = q[q["split"] == "train"]
        ix = city_index.build(ref, views)
        xy = dict(zip(ref["obj_idx"].astype(int), ref[["x_m", "y_m"]].to_numpy(float)))
        own = q[q["scene"].astype(str) == str(s)]
        rows += city_anchor_errors(
            ix,
            views,
            anchors(own, split, beyond, seed)[::every],
            settings,
            lambda m, xy=xy: np.array([xy[int(o)] for o in m]).reshape(-1, 2),
            cfg,
            solver_cfg,
            seq,
            learned,
            f"simulated-{n_objects}",
        )
        if log is not None:
            log.info("scene %s: %d objects, %d rows", s, len(ref), len(rows))
    out = pd.DataFrame(rows)
    out.attrs["objects"] = int(round(np.mean(sizes))) if sizes else 0
    return out


def warm_up_sequence() -> None:
    """Compile (or load) the sequence kernels on a tiny problem, so timed sequences exclude it."""
    rng = np.random.default_rng(0)
    ref, ref_cls = rng.uniform(-50, 50, (30, 2)), rng.integers(0, 3, 30)
    frames = [(rng.uniform(1, 20, (5, 2)), ref_cls[:5]), (rng.uniform(1, 20, (4, 2)), ref_cls[5:9])]
    rel = np.array([[0, 0, 0], [2.0, 0.5, 0.1]])
    prior, seen = rng.uniform(-50, 50, (20, 3)), rng.random((20, 30)) < 0.3
    solver.locate_sequence(
        frames,
        rel,
        ref,
        ref_cls,
        {"covis_weight": 1.0},
        solver.TrainingPriors(prior, seen, (2.0, 0.5)),
        None,
        np.full((2, 2), 0.1),
        solver.Fix(0.0, 0.0, 30.0),
    )
    true_match_poses(frames, rel, [ref[:5], ref[5:9]], np.zeros(3), np.ones(2))


def summary(errors: pd.DataFrame) -> dict:
    """The table's figures of one setting (rows of one map, frames, sigma and camera prior)."""
    em, ed = errors["error_m"].to_numpy(float), errors["error_deg"].to_numpy(float)
    s = metrics.summarise(errors)
    used = errors["frames_used"].to_numpy(float)
    cpu = errors["cpu_seconds"].to_numpy(float)
    bm, bd = errors["bound_error_m"].to_numpy(float), errors["bound_error_deg"].to_numpy(float)
    out = {k: s[k] for k in ["queries", "median_m", "median_deg", *metrics.RECALL_COLUMNS]}
    out.update(
        within_5m_5deg=float(100 * np.mean((em < WITHIN_M) & (ed < WITHIN_DEG))),
        within_5m_5deg_every_frame=float(100 * errors["frames_within"].sum() / max(used.sum(), 1)),
        wrong_scene_pct=float(100 * np.mean(np.isfinite(em) & (em > WRONG_SCENE_M))),
        no_pose_pct=float(100 * np.mean(~np.isfinite(em))),
        cpu_median_ms=float(1000 * np.median(cpu)),
        cpu_p90_ms=float(1000 * np.percentile(cpu, 90)),
        mean_frames=float(used.mean()),
        bound_median_m=float(np.median(bm)),
        bound_within_5m_5deg=float(100 * np.mean((bm < WITHIN_M) & (bd < WITHIN_DEG))),
    )
    out.update({k: s[k] for k in metrics.ANSWER_COLUMNS})
    return out


def summaries(errors: pd.DataFrame, objects: dict[str, int] | None = None) -> list[dict]:
    """One summary per (map, frames, GPS sigma, camera prior) of ``errors``; ``objects``: mean
    objects of each map."""
    out = []
    key = errors["gps_sigma_m"].fillna(-1.0)
    for (m, k, g, cam), e in errors.groupby(["map", "frames", key, "camera_prior"], sort=True):
        row = {
            "map": str(m),
            "objects": int((objects or {}).get(str(m), 0)),
            "frames": int(k),
            "gps_sigma_m": float(g) if g >= 0 else float("nan"),
            "camera_prior": str(cam),
        }
        row.update(summary(e))
        out.append(row)
    return out
