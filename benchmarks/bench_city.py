"""Where a city query's time goes, and how it grows with the map (reads results/ or a copy of it).

    python benchmarks/bench_city.py --root results [--split val] [--objects 2354 10000 100000] [--every 2]
    python benchmarks/bench_city.py --root results --solver-objects 2354 10000   # today's solver too
    python benchmarks/bench_city.py --root results --objects --bound             # what bounds the wrong scenes

Each benchmark scene's queries are localized in a city of that scene and synthetic tiles of the
other scenes (rule city_simulate's cities) of each size. Prints, per size, the CPU per query of
the city search's stages (ranking the views, the regions' objects and priors, the solver) median
and p90, the index's build time and size, the share of queries whose true place is among the
regions, % within (5 m, 5 deg) and % wrong scene; with ``--solver-objects``, today's whole-map
solver on the same cities (its co-visibility matrix is views x objects: keep these sizes small).
Priors (depth scale, verifier) are fitted here as rule city_priors fits them.

``--bound``: how often a query is explained better elsewhere than where it was taken, whatever
searches for it: the MSAC cost (data and priors) of the solver's best pose at the right place
(its oracle GT-BB box) against its best pose in each other scene (with that scene's priors), per
number of query objects.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fine_solver import load  # noqa: E402

from flatlandia import (  # noqa: E402
    config,
    proposals,
    solver,  # noqa: E402
)
from flatlandia.city import evaluation, index, search, simulate  # noqa: E402
from flatlandia.data import localmaps  # noqa: E402


def stages(ix, queries, cfg, settings, learned) -> pd.DataFrame:
    """CPU seconds of each stage of the search, per query, and its errors."""
    rows = []
    for r in queries.itertuples(index=False):
        q, q_cls = localmaps.local_map(r, "depth"), np.asarray(r.classes)
        c0 = time.process_time()
        views, _ = search.view_scores(ix, q, q_cls, cfg)
        centres = search.region_centres(ix, views, cfg)
        c1 = time.process_time()
        rows_, cams, seen = search.region_priors(ix, centres, cfg, settings.prior_radius_m)
        c2 = time.process_time()
        given = search.region_training_priors(ix, cams, seen, learned)
        sol = solver.solve(q, q_cls, ix.obj_xy[rows_], ix.obj_cls[rows_], False, settings, given)
        c3 = time.process_time()
        e_m = np.hypot(sol.x - r.x_m, sol.y - r.y_m) if sol else np.inf
        e_deg = abs(np.degrees(np.angle(np.exp(1j * (sol.theta - np.radians(r.theta_deg)))))) if sol else 180.0
        near = np.hypot(*(centres - [r.x_m, r.y_m]).T).min() <= cfg.nms_m
        rows.append(dict(rank=c1 - c0, regions=c2 - c1, solve=c3 - c2, error_m=e_m, error_deg=e_deg, hit=near))
    return pd.DataFrame(rows)


def scene_priors(ref, q, solver_dict, scale):
    """(map xy, classes, the scene's training priors with ``scale``, obj_idx -> row) of one scene,
    as fine_eval has them (without the verifier)."""
    given = solver.TrainingPriors(*solver.scene_priors(ref, q, solver_dict)[:2], scale)
    col = {int(o): k for k, o in enumerate(ref["obj_idx"])}
    return ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy(), given, col


def ambiguity(scenes, split, settings, solver_dict, scale) -> pd.DataFrame:
    """Per query: the cost of the best pose at the right place and the lowest cost of a pose in any
    other scene (the solver without its verifier: the cheapest pose)."""
    sp = {s: scene_priors(r, q, solver_dict, scale) for s, r, q in scenes}
    rows = []
    for s, _, q in scenes:
        xy, cls, given, col = sp[s]
        for r in q[q["split"] == split].itertuples(index=False):
            lm, q_cls = localmaps.local_map(r, "depth"), np.asarray(r.classes)
            box = proposals.gtbb_indices(xy, [col[int(o)] for o in r.ref_idx], [r.x_m, r.y_m])
            right = solver.solve(lm, q_cls, xy[box], cls[box], False, settings, given.rows(box))
            other = [solver.solve(lm, q_cls, x, c, False, settings, g) for t, (x, c, g, _) in sp.items() if t != s]
            rows.append(
                dict(
                    m=r.n_objects,
                    right=right.cost if right else np.inf,
                    other=min((o.cost for o in other if o is not None), default=np.inf),
                )
            )
    return pd.DataFrame(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("results"))
    ap.add_argument("--split", default="val")
    ap.add_argument("--objects", type=int, nargs="*", default=[2354, 10000, 100000])
    ap.add_argument("--solver-objects", type=int, nargs="*", default=[])
    ap.add_argument("--every", type=int, default=1, help="every k-th query")
    ap.add_argument("--bound", action="store_true", help="measure how often another scene explains a query better")
    args = ap.parse_args()
    scenes = load(args.root)
    solver_dict = config.section_defaults("solver")
    settings, cfg = solver.SolverConfig.from_dict(solver_dict), search.SearchConfig()
    sim = config.section_defaults("city.simulate")
    c0 = time.process_time()
    learned = solver.learned_priors.fit([(r, q) for _, r, q in scenes], solver_dict)
    print(f"priors fitted in {time.process_time() - c0:.1f} s CPU")
    solver.warm_up()
    if args.bound:
        a = ambiguity(scenes, args.split, settings, solver_dict, learned.scale)
        worse = a["other"] <= a["right"]
        print(
            f"another scene explains the query at a lower cost than the right place: {100 * worse.mean():.1f} % of {len(a)}"
        )
        by_m = a.assign(worse=worse).groupby(np.minimum(a["m"], 9))["worse"].agg(["size", "mean"])
        print(
            "  by objects (9 = 9 or more): "
            + ", ".join(f"{m}: {100 * r['mean']:.0f} % of {int(r['size'])}" for m, r in by_m.iterrows())
        )
    names = [s for s, _, _ in scenes]
    refs, queries = {s: r for s, r, _ in scenes}, {s: q for s, _, q in scenes}
    spacing_m, seed = config.section_defaults("city")["spacing_m"], config.section_defaults()["seed"]
    for n in sorted(set(args.objects) | set(args.solver_objects)):
        parts, whole, build = [], [], []
        # rule city_simulate's cities (its seed and spacing), built by the same function
        for s, ref, cq in simulate.scene_cities(names, refs, queries, n, spacing_m, sim["jitter_m"], seed, args.split):
            test = queries[s][queries[s]["split"] == args.split].iloc[:: args.every]
            c0 = time.process_time()
            ix = index.build(ref, cq[cq["split"] == "train"])
            build.append((time.process_time() - c0, ix.nbytes() / 1e6))
            mine = cq[(cq["scene"] == s) & cq["token"].isin(test["token"])]
            if n in args.objects:
                parts.append(stages(ix, mine, cfg, settings, learned))
            if n in args.solver_objects:
                keep = (cq["split"] == "train") | cq["token"].isin(mine["token"])
                whole.append(evaluation.solver_errors(ref, cq[keep], args.split, solver_dict, learned))
        b = np.array(build)
        print(f"\n{n:,} objects: index build {b[:, 0].mean():.2f} s CPU, {b[:, 1].mean():.2f} MB (mean per city)")
        if parts:
            e = pd.concat(parts, ignore_index=True)
            ms = 1000 * e[["rank", "regions", "solve"]]
            total = ms.sum(axis=1)
            print(
                "  city search CPU ms median / p90: "
                + ", ".join(f"{c} {ms[c].median():.1f} / {ms[c].quantile(0.9):.1f}" for c in ms)
                + f", total {total.median():.1f} / {total.quantile(0.9):.1f}"
            )
            ok = (e["error_m"] < 5) & (e["error_deg"] < 5)
            wrong = np.isfinite(e["error_m"]) & (e["error_m"] > evaluation.WRONG_SCENE_M)
            print(
                f"  n={len(e)} true place in regions {100 * e['hit'].mean():.1f} %, within (5 m, 5 deg) {100 * ok.mean():.1f} %, wrong scene {100 * wrong.mean():.1f} %"
            )
        if whole:
            s = evaluation.summary(pd.concat(whole, ignore_index=True))
            print(
                f"  today's whole-map solver: CPU ms median / p90 {s['cpu_median_ms']:.1f} / {s['cpu_p90_ms']:.1f}, "
                f"within (5 m, 5 deg) {s['within_5m_5deg']:.1f} %, wrong scene {s['wrong_scene_pct']:.1f} %"
            )


if __name__ == "__main__":
    main()
