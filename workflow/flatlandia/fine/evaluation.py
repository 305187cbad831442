"""Fine 3DoF localization: proposals, per-query errors, summaries and the paper-style tables.

Errors are true metres (scene metric frame) and degrees. The paper reports local-map units x
215 as "metres" (PAPER.md, caution on units); ``error_paper_m`` gives that convention so rows
can be read against its Tables 4 and 5, but our headline figures are true metres.

Proposal tables share one shape: columns ``scene, token, strategy, proposal`` (list of
reference ``obj_idx``). :func:`gtbb_proposals` builds the oracle (reference objects inside the
axis-aligned box around the query's matched objects and the true camera, enlarged 10%),
:func:`whole_map_proposals` the whole reference map; coarse localization writes the same shape.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.data import localmaps
from flatlandia.data.registration import UNIT_DEG
from flatlandia.fine import solver

#: the paper's accuracy thresholds (metres, degrees)
THRESHOLDS: list[tuple[float, float]] = [(0.5, 2.0), (1.0, 5.0), (5.0, 10.0), (10.0, 20.0)]
GROSS_M = 30.0

#: The paper's Table 4 (GT-BB proposals): % under thresholds, median "m" (units x 215), median deg.
PAPER_TABLE4 = {
    ("MLP", "gt"): (0.0, 0.5, 10.0, 37.0, 12.5, 13.0),
    ("MLP", "depth"): (0.0, 1.9, 16.6, 36.0, 13.3, 12.9),
    ("MLP+ATT", "gt"): (0.0, 0.0, 13.3, 32.2, 12.8, 14.2),
    ("MLP+ATT", "depth"): (0.0, 0.5, 5.7, 25.6, 15.5, 17.9),
    ("GAT", "gt"): (0.0, 0.0, 3.3, 13.7, 19.0, 22.1),
    ("GAT", "depth"): (0.0, 0.0, 4.7, 17.1, 21.3, 15.9),
    ("GAT+ATT", "gt"): (0.0, 0.0, 8.1, 21.3, 18.2, 14.2),
    ("GAT+ATT", "depth"): (0.0, 0.5, 2.4, 16.1, 19.3, 21.1),
}
PAPER_QT_S = 0.02  # the paper's MLP query time
#: The paper's Table 5 (coarse proposals 2N_LM, best rows, MLP): median "m", median deg.
PAPER_TABLE5 = {("MLP", "Sim+Trip", "gt"): (25.1, 25.8), ("MLP", "Sim+Trip", "depth"): (25.3, 24.4)}


# ----------------------------------------------------------------------------- proposals


def gtbb_indices(ref_xy: np.ndarray, matched, cam_xy, enlarge: float = 0.10) -> np.ndarray:
    """Reference rows inside the box around the matched objects and the camera, enlarged by ``enlarge``."""
    ref_xy = np.asarray(ref_xy, float)
    pts = np.vstack([ref_xy[np.asarray(list(matched), int)], np.asarray(cam_xy, float).reshape(1, 2)])
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * (1 + enlarge)
    return np.flatnonzero(np.all(np.abs(ref_xy - centre) <= half + 1e-9, axis=1))


def training_priors(queries: pd.DataFrame, config: dict | None = None):
    """The solver's priors from one scene's training split: (prior cameras (P, 3) as x, y, heading
    in radians, or None when ``camera_prior`` is off; per prior camera the reference ``obj_idx`` it
    saw, for the co-visibility cost, or None). Test queries never contribute."""
    cfg = dict(config or {})
    if not cfg.get("camera_prior", True):
        return None, None
    tr = queries[queries["split"] == "train"]
    prior = np.column_stack([tr["x_m"], tr["y_m"], np.radians(tr["theta_deg"])]).astype(float)
    seen = [np.asarray(v, int) for v in tr["ref_idx"]] if float(cfg.get("covis_weight", 0)) > 0 else None
    return prior, seen


def gtbb_proposals(ref: pd.DataFrame, queries: pd.DataFrame, enlarge: float = 0.10) -> pd.DataFrame:
    """The oracle GT-BB proposal of every query (``proposal`` holds reference ``obj_idx``)."""
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    rows = []
    for r in queries.itertuples(index=False):
        rows_idx = [pos[int(i)] for i in r.ref_idx]
        idx = gtbb_indices(ref_xy, rows_idx, [r.x_m, r.y_m], enlarge)
        rows.append(
            {"scene": str(r.scene), "token": str(r.token), "strategy": "GT-BB", "proposal": [int(o) for o in obj[idx]]}
        )
    return pd.DataFrame(rows, columns=["scene", "token", "strategy", "proposal"])


def simulated_coarse_proposals(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    rng: np.random.Generator,
    recall: float = 0.5,
    size_factor: float = 2.0,
    fp_scale_m: float = 30.0,
) -> pd.DataFrame:
    """Proposals that look like a coarse model's 2N_LM, for training the learned models on them.

    Why: a model trained on GT-BB proposals only has never seen wrong objects, and a coarse
    proposal holds about half. Measured on the test split's Sim+Trip 2N_LM proposals: recall 0.52,
    precision 0.26, 95 % of wrong objects of a class the query sees, median 16 m from a true one.
    So each true object is kept with probability ``recall`` (at least one), and wrong objects of
    the query's classes fill ``size_factor`` x N, drawn with weight exp(-d / ``fp_scale_m``), d the
    distance to the nearest true object. Uses ground truth: training split only.
    """
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    obj = ref["obj_idx"].to_numpy()
    pos = {int(o): k for k, o in enumerate(obj)}
    rows = []
    for r in queries.itertuples(index=False):
        true = np.array([pos[int(i)] for i in r.ref_idx], int)
        keep = true[rng.random(len(true)) < recall]
        if not len(keep):
            keep = true[rng.integers(len(true), size=1)]
        n_fp = max(int(round(size_factor * len(true))) - len(keep), 0)
        others = np.setdiff1d(np.nonzero(np.isin(ref_cls, np.asarray(r.classes, int)))[0], true)
        if n_fp and len(others):
            d = np.linalg.norm(ref_xy[others, None] - ref_xy[None, true], axis=-1).min(1)
            w = np.exp(-d / fp_scale_m)
            fp = rng.choice(others, size=min(n_fp, len(others)), replace=False, p=w / w.sum())
            keep = np.concatenate([keep, fp])
        rows.append(
            {
                "scene": str(r.scene),
                "token": str(r.token),
                "strategy": "simulated 2N_LM",
                "proposal": [int(o) for o in obj[np.sort(keep)]],
            }
        )
    return pd.DataFrame(rows, columns=["scene", "token", "strategy", "proposal"])


def crop_to_densest(ref: pd.DataFrame, proposals: pd.DataFrame, radius_m: float) -> pd.DataFrame:
    """Each proposal cut down to its objects within ``radius_m`` of its densest object (the one
    with most proposal objects within ``radius_m``; ties to the first).

    Why: a coarse 2N_LM proposal is about half wrong objects scattered over the map, and a learned
    model centres its frame on the proposal: measured on the test split's Sim+Trip 2N_LM depth
    proposals with the GT-BB-trained MLP, cropping to 30 m takes the median from 29.5 to 22.9 m.
    ``radius_m <= 0`` returns the proposals unchanged.
    """
    if radius_m <= 0:
        return proposals
    xy = dict(zip(ref["obj_idx"].astype(int), ref[["x_m", "y_m"]].to_numpy()))
    out = []
    for prop in proposals["proposal"]:
        objs = [int(o) for o in prop if int(o) in xy]
        if len(objs) < 2:
            out.append(objs)
            continue
        p = np.array([xy[o] for o in objs])
        near = np.linalg.norm(p[:, None] - p[None], axis=-1) < radius_m
        out.append([o for o, k in zip(objs, near[np.argmax(near.sum(1))]) if k])
    return proposals.assign(proposal=out)


def training_proposals(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    regime: str,
    rng: np.random.Generator,
    copies: int = 2,
    keep_gtbb: bool = True,
    crop_m: float = 0.0,
) -> list[pd.DataFrame]:
    """The proposal tables a learned model trains (or validates) on, one sample per query and table.

    ``regime`` ``gtbb``: the oracle GT-BB proposal (the paper's training). ``coarse``: ``copies``
    simulated coarse proposals per query (:func:`simulated_coarse_proposals`, cut by
    :func:`crop_to_densest` to ``crop_m`` like the real ones at evaluation), plus GT-BB when
    ``keep_gtbb``. Why: a model that never saw wrong objects in training does worse on coarse
    proposals (measured in the README). Uses ground truth: training and validation splits only.
    """
    if regime == "gtbb":
        return [gtbb_proposals(ref, queries)]
    if regime != "coarse":
        raise ValueError(f"training proposals must be gtbb or coarse, got {regime!r}")
    out = [gtbb_proposals(ref, queries)] if keep_gtbb else []
    out += [crop_to_densest(ref, simulated_coarse_proposals(ref, queries, rng), crop_m) for _ in range(copies)]
    return out


def training_label(regime: str, crop_m: float = 0.0) -> str:
    """How a learned model was trained, for the tables: '' (solver), 'GT-BB' or 'simulated coarse ...'."""
    if not regime:
        return ""
    if regime == "gtbb":
        return "GT-BB"
    return "simulated coarse" + (f", cut to {crop_m:g} m" if crop_m > 0 else "")


def whole_map_proposals(ref: pd.DataFrame, queries: pd.DataFrame) -> pd.DataFrame:
    obj = [int(o) for o in ref["obj_idx"]]
    return pd.DataFrame(
        [
            {"scene": str(r.scene), "token": str(r.token), "strategy": "whole", "proposal": obj}
            for r in queries.itertuples(index=False)
        ],
        columns=["scene", "token", "strategy", "proposal"],
    )


def solvable(query_classes, proposal_classes, min_objects: int = 3) -> bool:
    """Can the proposal hold a solution: at least ``min_objects`` objects of the query's classes.

    Counted as a multiset match: each query object can use one proposal object of its class.
    """
    need = pd.Series(list(query_classes)).value_counts()
    have = pd.Series(list(proposal_classes)).value_counts()
    usable = sum(min(int(n), int(have.get(c, 0))) for c, n in need.items())
    return usable >= min_objects


# ----------------------------------------------------------------------------- errors


def pose_errors(x, y, theta_rad, gt_x, gt_y, gt_theta_rad):
    """Position error (m) and absolute wrapped heading error (deg); vectorised."""
    e_m = np.hypot(np.asarray(x, float) - gt_x, np.asarray(y, float) - gt_y)
    e_deg = np.abs(np.degrees(geo.wrap_angle(np.asarray(theta_rad, float) - np.asarray(gt_theta_rad, float))))
    return e_m, e_deg


@functools.lru_cache(maxsize=256)
def metres_per_unit(lat: float) -> float:
    """Mean true metres per published local-map unit (tf/2 degrees) at a latitude (cached: a
    projection is built per call, 18 ms, and evaluation asks once per query)."""
    mx, my = geo.MetricFrame(0.0, float(lat)).metres_per_degree()
    return UNIT_DEG * (mx + my) / 2


def paper_metres(error_m, lat: float):
    """A true-metre error in the paper's convention (local-map units x 215)."""
    return np.asarray(error_m, float) / metres_per_unit(lat) * geo.PAPER_METRES_PER_UNIT


def summarise(errors: pd.DataFrame) -> dict:
    """Median errors, % under the paper's thresholds, F%, gross share, mean/median query time.

    Failed queries (no pose) count with infinite error. ``F%`` is the share of queries whose
    proposal cannot hold a solution (fewer than 3 objects of the query's classes).
    """
    e = errors
    em = e["error_m"].to_numpy(float)
    ed = e["error_deg"].to_numpy(float)
    out = {
        "queries": int(len(e)),
        "median_m": float(np.median(em)) if len(e) else float("nan"),
        "median_deg": float(np.median(ed)) if len(e) else float("nan"),
    }
    for m, d in THRESHOLDS:
        out[f"pct_{m:g}m_{d:g}deg"] = float(100 * np.mean((em < m) & (ed < d))) if len(e) else float("nan")
    out["failure_pct"] = float(100 * np.mean(~e["solvable"].to_numpy(bool))) if len(e) else float("nan")
    out["no_pose_pct"] = float(100 * np.mean(~np.isfinite(em))) if len(e) else float("nan")
    out["gross_pct"] = float(100 * np.mean(em > GROSS_M)) if len(e) else float("nan")
    out["mean_query_s"] = float(e["seconds"].mean()) if len(e) else float("nan")
    out["median_query_s"] = float(e["seconds"].median()) if len(e) else float("nan")
    if "cpu_seconds" in e:  # CPU time of the process: robust to other load on a shared machine
        out["median_query_cpu_s"] = float(e["cpu_seconds"].median()) if len(e) else float("nan")
    if "error_paper_m" in e:  # the paper's convention: local-map units x 215, same thresholds
        pu = e["error_paper_m"].to_numpy(float)
        out["median_pu"] = float(np.median(pu)) if len(e) else float("nan")
        for m, d in THRESHOLDS:
            out[f"pct_pu_{m:g}m_{d:g}deg"] = float(100 * np.mean((pu < m) & (ed < d))) if len(e) else float("nan")
    return out


def ref_map_kb(ref: pd.DataFrame) -> float:
    """Size of a reference map as the methods read it: 2 x float32 + a class byte per object, kB."""
    return 9 * len(ref) / 1000


def json_safe(d: dict) -> dict:
    """Non-finite floats as None (JSON has no inf/NaN)."""
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


# ----------------------------------------------------------------------------- solver evaluation


def local_map(row, map_type: str) -> np.ndarray:
    if map_type == "gt":
        return localmaps.xy(row.gt_local_xy_m)
    if map_type == "depth":
        return localmaps.xy(row.depth_local_xy)
    raise ValueError(f"map_type must be gt or depth, got {map_type!r}")


def evaluate_solver(
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    map_type: str,
    config: dict | None = None,
    prior_xy: np.ndarray | None = None,
    scale_prior: tuple[float, float] | None = None,
    method: str = "solver",
    progress: Callable | None = None,
    prior_seen: list | None = None,
) -> pd.DataFrame:
    """Run the geometric solver on every query of one scene; one row of errors per query.

    ``proposals`` has the shape scene, token, strategy, proposal (reference obj_idx); queries
    without a proposal row get an empty proposal (counted as failures). ``prior_seen``: per prior
    camera (rows of ``prior_xy``), the reference ``obj_idx`` it saw (training queries' ``ref_idx``),
    for the solver's co-visibility cost.
    """
    cfg = solver.SolverConfig.from_dict(config)
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    lat = float(ref["lat"].mean())
    props = {str(t): (s, p) for t, s, p in zip(proposals["token"], proposals["strategy"], proposals["proposal"])}
    seen = None
    if prior_seen is not None and prior_xy is not None:
        seen = np.zeros((len(prior_seen), len(ref_xy)), bool)
        for k, objs in enumerate(prior_seen):
            seen[k, [pos[int(o)] for o in objs if int(o) in pos]] = True
    solver.warm_up()  # query times without the kernels' compilation
    rows = []
    items = list(queries.itertuples(index=False))
    for r in progress(items) if progress else items:
        strategy, prop = props.get(str(r.token), ("none", []))
        idx = np.array([pos[int(o)] for o in prop if int(o) in pos], int)
        q = local_map(r, map_type)
        t0, c0 = time.perf_counter(), time.process_time()
        sol = (
            solver.solve(
                q,
                np.asarray(r.classes),
                ref_xy[idx],
                ref_cls[idx],
                metric=(map_type == "gt"),
                config=cfg,
                prior_xy=prior_xy,
                scale_prior=scale_prior,
                prior_seen=seen[:, idx] if seen is not None else None,
            )
            if len(idx) >= 2
            else None
        )
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        rows.append(_row(r, map_type, strategy, method, sol, dt, idx, ref_cls, lat, pos, ref) | {"cpu_seconds": dc})
    return pd.DataFrame(rows)


def _row(r, map_type, strategy, method, sol, dt, idx, ref_cls, lat, pos, ref):
    if sol is None:
        x = y = th = np.nan
        e_m, e_deg, conf, n_inl, correct = np.inf, 180.0, 0.0, 0, 0
    else:
        x, y, th = sol.x, sol.y, sol.theta
        e_m, e_deg = pose_errors(x, y, th, r.x_m, r.y_m, np.radians(r.theta_deg))
        conf, n_inl = sol.confidence, len(sol.inliers)
        obj = ref["obj_idx"].to_numpy()
        truth = [int(o) for o in r.ref_idx]
        correct = sum(int(obj[idx[c]]) == truth[k] for k, c in sol.inliers)
    return {
        "scene": str(r.scene),
        "token": str(r.token),
        "method": method,
        "map_type": map_type,
        "strategy": strategy,
        "n_objects": int(r.n_objects),
        "proposal_size": int(len(idx)),
        "solvable": bool(solvable(r.classes, ref_cls[idx])) if len(idx) else False,
        "x": float(x),
        "y": float(y),
        "theta_deg": float(np.degrees(th)) if np.isfinite(th) else float("nan"),
        "error_m": float(e_m),
        "error_deg": float(e_deg),
        "error_paper_m": float(paper_metres(e_m, lat)),
        "confidence": float(conf),
        "n_inliers": int(n_inl),
        "n_correct_inliers": int(correct),
        "seconds": float(dt),
    }


# ----------------------------------------------------------------------------- tables

_TH_COLS = [f"pct_{m:g}m_{d:g}deg" for m, d in THRESHOLDS]
_PU_COLS = [f"pct_pu_{m:g}m_{d:g}deg" for m, d in THRESHOLDS]


#: method slugs (rule wildcards) and their display names
METHOD_LABELS = {"geo": "geometric solver", "mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}


def paper_row(label: str, map_type: str, strategy: str):
    """(name, values) of the paper's row beside ours: Table 4 by model (its best, MLP, for the
    solver) for GT-BB; Table 5's best (MLP, Sim+Trip 2N_LM) for coarse proposals and the whole map.
    values = (4 threshold %, median "m", median deg, query ms); NaN where the paper gives none."""
    nan = float("nan")
    if strategy == "GT-BB":
        p = PAPER_TABLE4.get((label, map_type))
        name = label
        if p is None:
            p, name = PAPER_TABLE4[("MLP", map_type)], "MLP (best)"
        qt = 1000 * PAPER_QT_S if name.startswith("MLP") and not name.startswith("MLP+") else nan
        return f"Table 4 {name}", (*p, qt)
    p5 = PAPER_TABLE5.get(("MLP", "Sim+Trip", map_type))
    if p5 is None:
        return "", (nan,) * 7
    return "Table 5 MLP Sim+Trip 2N_LM (best)", (nan, nan, nan, nan, p5[0], p5[1], 1000 * PAPER_QT_S)


def table_rows(summaries: list[dict]) -> pd.DataFrame:
    """The ``fine_localization`` table (schema in tables.SCHEMAS): one row per run summary, the
    paper's row beside it."""
    nan = float("nan")
    rows = []
    for s in summaries:
        run = s.get("run", "")
        method = s.get("method_slug") or (run.rsplit("_", 2)[0] if run else "")
        label = METHOD_LABELS.get(method, s.get("method", method))
        strategy = s.get("strategy", "")
        name, p = paper_row(label, s.get("map_type", ""), strategy)

        def f(k, scale=1.0, s=s):
            v = s.get(k)
            return nan if v is None else float(v) * scale

        row = {
            "run": run,
            "method": method,
            "method_label": label,
            "map_type": s.get("map_type", ""),
            "proposal": s.get("proposal", run.rsplit("_", 1)[-1] if run else ""),
            "strategy": strategy,
            "queries": int(s.get("queries", 0)),
            "median_m": f("median_m"),
            "median_deg": f("median_deg"),
        }
        row.update({c: f(c) for c in _TH_COLS})
        row.update(
            failure_pct=f("failure_pct"),
            no_pose_pct=f("no_pose_pct"),
            gross_pct=f("gross_pct"),
            median_query_ms=f("median_query_s", 1000),
            mean_query_ms=f("mean_query_s", 1000),
            median_query_cpu_ms=f("median_query_cpu_s", 1000),
            train_s=f("train_s") if s.get("train_s") is not None else 0.0,
            epochs=int(s.get("epochs") or 0),
            n_parameters=int(s.get("n_parameters") or 0),
            model_mb=float(s.get("model_mb") or 0.0),
            ref_map_kb=f("ref_map_kb"),
            median_pu=f("median_pu"),
            trained_on=str(s.get("trained_on") or ("GT-BB" if method != "geo" else "")),
        )
        row.update({c: f(c) for c in _PU_COLS})
        row["paper_row"] = name
        row.update({f"paper_{c}": float(v) for c, v in zip(_TH_COLS, p[:4])})
        row.update(paper_median_pu=float(p[4]), paper_median_deg=float(p[5]), paper_query_ms=float(p[6]))
        rows.append(row)
    from flatlandia.tables import SCHEMAS

    cols = [c.name for c in SCHEMAS["fine_localization"]]
    return pd.DataFrame(rows, columns=cols)


def render_markdown(df: pd.DataFrame, note: str = "") -> str:
    """Tables 4 (GT-BB) and 5 (coarse proposals, whole map) laid out like the paper, its values beside ours."""

    def fmt(v, spec):
        return "–" if v is None or not np.isfinite(v) else format(v, spec)

    def cell(r):
        pct = " / ".join(fmt(r[c], ".1f") for c in _TH_COLS)
        out = (
            f"{pct}; {fmt(r['median_m'], '.2f')} m ({fmt(r['median_pu'], '.2f')} pu); {fmt(r['median_deg'], '.1f')}°; "
            f"QT {fmt(r['median_query_ms'], '.1f')} ms (CPU {fmt(r['median_query_cpu_ms'], '.1f')} ms); F {fmt(r['failure_pct'], '.1f')}%; "
            f"gross {fmt(r['gross_pct'], '.1f')}%"
        )
        if r["epochs"]:
            out += f"; train {fmt(r['train_s'] / 60, '.1f')} min ({r['epochs']} ep, {r['trained_on'] or 'GT-BB'})"
        return out

    def paper_cell(r):
        if not r["paper_row"]:
            return "—"
        pre = "" if r["paper_row"].endswith(r["method_label"]) else r["paper_row"].split(" ", 2)[-1] + ": "
        pct = (
            " / ".join(fmt(r[f"paper_{c}"], "g") for c in _TH_COLS) + "; "
            if np.isfinite(r[f"paper_{_TH_COLS[0]}"])
            else ""
        )
        qt = f"; {fmt(r['paper_query_ms'], 'g')} ms" if np.isfinite(r["paper_query_ms"]) else ""
        return f'{pre}{pct}{fmt(r["paper_median_pu"], "g")} "m"; {fmt(r["paper_median_deg"], "g")}°{qt}'

    out = [
        "# Fine 3DoF localization (test split)",
        "",
        "Cells: % within (0.5 m, 2°) / (1 m, 5°) / (5 m, 10°) / (10 m, 20°) in true metres; median error in true "
        "metres (in brackets, `pu`: the paper's convention, local-map units x 215); median degrees; median query "
        "time (one CPU thread); F% (proposal holds fewer than 3 objects of the query's classes); gross errors "
        "(> 30 m); training time (one CPU thread) for learned models.",
        'The paper\'s columns are its own figures, whose metres are units x 215 ("m"). GT local maps are exact '
        "rigid copies of the reference map: on them the task is pure registration.",
        "",
    ]
    if note:
        out += [note, ""]
    for title, mask in (
        ("Table 4 (GT-BB proposals)", df["strategy"] == "GT-BB"),
        ("Table 5 (coarse proposals and whole map)", df["strategy"] != "GT-BB"),
    ):
        part = df[mask]
        if part.empty:
            continue
        out += [
            f"## {title}",
            "",
            "| method | proposal | GT maps (ours) | GT maps (paper) | depth maps (ours) | "
            "depth maps (paper) | params / model / map |",
            "|---|---|---|---|---|---|---|",
        ]
        for (label, strategy), g in part.groupby(["method_label", "strategy"], sort=False):
            cells = []
            for mt in ("gt", "depth"):
                r = g[g["map_type"] == mt]
                cells += [cell(r.iloc[0]), paper_cell(r.iloc[0])] if len(r) else ["—", "—"]
            r0 = g.iloc[0]
            size = (
                f"{r0['n_parameters']:,} / {r0['model_mb']:.2f} MB / {r0['ref_map_kb']:.2f} kB"
                if r0["n_parameters"]
                else f"– / – / {r0['ref_map_kb']:.2f} kB"
            )
            out.append(f"| {label} | {strategy} | " + " | ".join(cells) + f" | {size} |")
        out.append("")
    return "\n".join(out) + "\n"
