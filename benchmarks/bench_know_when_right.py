"""Issue 43's figures on a finished run: how often nonsense is `ok`, the sequences' probability at
two odometry noise levels, and the headline figures with their bootstrap intervals.

    python benchmarks/bench_know_when_right.py --root results nonsense [--split test] [--map-type gt]
    python benchmarks/bench_know_when_right.py --root results noise [--levels 1 3] [--frames 1 5]
    python benchmarks/bench_know_when_right.py --root results intervals

``nonsense``: one nonsense query of each kind (flatlandia.solver.nonsense: real classes at random
places, the map's classes at random places, another scene's query) per query of the split, solved
on the whole map with the run's priors (results/solver/priors/whole.json; GT maps: whole.gt.json,
nonsense in metres) as rule fine_eval does; prints the % answered `ok`, `ambiguous`, `no pose` per
kind and for the real queries, and how many real `ok` answers are right. ``noise``: the sequence rows of rule
beyond_scene (scene maps, no fix) at each multiple of the protocol's odometry noise; % within
(5 m, 5 deg), the answerable share at >= 95 % within and the ECE. ``intervals``: each headline
figure of the run's tables (the solver's depth whole-map row, the sequence and city rows where they
exist) with its 95 % bootstrap interval over the queries (2,000 resamples, seed 0). Seeds from the
run's config (the `seed` key of config/config.yaml unless --seed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia import config, localize, solver  # noqa: E402
from flatlandia.sequences import evaluation as sequences  # noqa: E402
from flatlandia.sequences import validation  # noqa: E402
from flatlandia.solver import calibration, nonsense  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def load(root: Path):
    out = []
    for s in sorted((p.name for p in root.iterdir() if p.name.isdigit()), key=int):
        r, q = root / s / "maps/reference_map.parquet", root / s / "queries/queries.parquet"
        if r.exists() and q.exists():
            out.append((pd.read_parquet(r), pd.read_parquet(q)))
    return out


def run_nonsense(root: Path, split: str, seed: int, map_type: str = "depth") -> None:
    scenes = load(root)
    metric = map_type == "gt"
    learned = solver.LearnedPriors.read(
        root / ("solver/priors/whole.gt.json" if metric else "solver/priors/whole.json")
    )
    cfg = solver.SolverConfig.from_dict(None)
    threshold = config.section_defaults("solver")["answer_probability"]
    solver.warm_up()
    priors = [solver.scene_priors(ref, q, None, learned) for ref, q in scenes]
    from flatlandia.data import localmaps

    records = [list(q[q["split"] == split].iterrows()) for _, q in scenes]
    real = [[(localmaps.local_map(r, map_type), np.asarray(r["classes"])) for _, r in rs] for rs in records]

    def solve(i, xy, cls):
        ref = scenes[i][0]
        return solver.locate(
            xy, cls, ref[["x_m", "y_m"]].to_numpy(), ref["class_id"].to_numpy(), metric, cfg, priors[i]
        ).best

    def status(best):
        return "no pose" if best is None else localize.answer_status(best, threshold)["status"]

    counts: dict[str, dict[str, int]] = {}
    right_ok = 0
    for i, rs in enumerate(records):
        for (xy, cls), (_, r) in zip(real[i], rs):
            best = solve(i, xy, cls)
            st = status(best)
            counts.setdefault("real", {}).setdefault(st, 0)
            counts["real"][st] += 1
            right_ok += int(st == "ok" and validation._right(best, r))
    cpu = []
    for n in nonsense.draw(real, [ref["class_id"].to_numpy() for ref, _ in scenes], seed + 1, metric=metric):
        c0 = time.process_time()
        best = solve(n.scene, n.xy, n.classes)
        cpu.append(time.process_time() - c0)
        counts.setdefault(n.kind, {}).setdefault(status(best), 0)
        counts[n.kind][status(best)] += 1
    total = {"ok": 0, "n": 0}
    for kind, c in counts.items():
        n = sum(c.values())
        if kind != "real":
            total["n"] += n
            total["ok"] += c.get("ok", 0)
        shares = ", ".join(f"{k} {100 * v / n:.1f} %" for k, v in sorted(c.items()))
        print(f"{kind} ({map_type}): {n} queries: {shares}")
    ok = counts.get("real", {}).get("ok", 0)
    print(f"real queries answered ok and right (5 m, 5 deg): {right_ok} of {ok}")
    print(f"nonsense, all kinds: {total['n']} queries, {100 * total['ok'] / max(total['n'], 1):.2f} % ok")
    print(f"CPU per nonsense query: median {1000 * np.median(cpu):.1f} ms")


def run_noise(root: Path, levels, frames, split: str, seed: int) -> None:
    scenes = load(root)
    learned = solver.LearnedPriors.read(root / "solver/priors/whole.json")
    beyond = yaml.safe_load((REPO / "config/config.yaml").read_text())["beyond"]
    grid = [sequences.Setting(int(k)) for k in frames]
    for level in levels:
        e = sequences.scene_errors(scenes, grid, None, validation.noisier(beyond, level), learned, seed, split)
        for k, part in e.groupby("frames"):
            em, ed = part["error_m"].to_numpy(float), part["error_deg"].to_numpy(float)
            within = (em < 5) & (ed < 5)
            p = part["probability"].to_numpy(float)
            print(
                f"odometry x{level:g} ({float(beyond['odometry_distance_pct']) * level:g} %, "
                f"{float(beyond['odometry_heading_deg']) * level:g} deg/step), {k} frames, {len(part)} anchors: "
                f"within {100 * within.mean():.1f} %, answerable at >= 95 % "
                f"{calibration.largest_coverage(p, ~within, 5.0):.1f} %, ECE {calibration.expected_calibration_error(p, within):.1f}"
            )


def bootstrap(values: np.ndarray, stat, n: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(statistic, 2.5 %, 97.5 %) of ``stat`` over resamples of the rows of ``values``."""
    rng = np.random.default_rng(seed)
    est = stat(values)
    draws = [stat(values[rng.integers(0, len(values), len(values))]) for _ in range(n)]
    lo, hi = np.percentile(draws, [2.5, 97.5])
    return float(est), float(lo), float(hi)


def headline(errors: pd.DataFrame, label: str, wrong_scene: bool = False) -> None:
    em, ed = errors["error_m"].to_numpy(float), errors["error_deg"].to_numpy(float)
    p = errors["probability"].to_numpy(float)
    rows = np.column_stack([em, ed, p])

    def within(v):
        return 100 * np.mean((v[:, 0] < 5) & (v[:, 1] < 5))

    def answerable(v):
        if wrong_scene:
            return calibration.largest_coverage(v[:, 2], np.isfinite(v[:, 0]) & (v[:, 0] > 500), 1.0)
        return calibration.largest_coverage(v[:, 2], ~((v[:, 0] < 5) & (v[:, 1] < 5)), 5.0)

    def ece(v):
        return calibration.expected_calibration_error(v[:, 2], (v[:, 0] < 5) & (v[:, 1] < 5))

    what = "answerable at <= 1 % wrong scene" if wrong_scene else "answerable at >= 95 % within"
    for name, stat in (("within (5 m, 5 deg)", within), (what, answerable), ("ECE", ece)):
        est, lo, hi = bootstrap(rows, stat)
        print(f"{label}: {name} {est:.1f} [{lo:.1f}, {hi:.1f}] ({len(rows)} queries)")


def run_intervals(root: Path) -> None:
    fine = root / "fine/solver_depth_whole/errors.parquet"
    if fine.exists():
        headline(pd.read_parquet(fine), "scene map, 1 frame")
    for path in sorted((root / "beyond").glob("*/errors*.parquet")):
        e = pd.read_parquet(path)
        e = e[e["gps_sigma_m"].isna() & (e["camera_prior"].astype(str) == "on")]
        for (m, k), part in e.groupby(["map", "frames"]):
            if k in (1, 5):
                headline(part, f"{m}, {k} frames", wrong_scene=not str(m).startswith("scene"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", type=Path, default=Path("results"))
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--split", default="test")
    ap.add_argument("--map-type", choices=("depth", "gt"), default="depth", help="nonsense: the local maps asked")
    ap.add_argument("what", choices=("nonsense", "noise", "intervals"))
    ap.add_argument("--levels", type=float, nargs="+", default=[1.0, 3.0])
    ap.add_argument("--frames", type=int, nargs="+", default=[1, 5])
    args = ap.parse_args(argv)
    seed = (
        args.seed if args.seed is not None else int(yaml.safe_load((REPO / "config/config.yaml").read_text())["seed"])
    )
    if args.what == "nonsense":
        run_nonsense(args.root, args.split, seed, args.map_type)
    elif args.what == "noise":
        run_noise(args.root, args.levels, args.frames, args.split, seed)
    else:
        run_intervals(args.root)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
