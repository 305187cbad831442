"""The targets of "Know when it is right" in one run (docs/results.md, "Knowing when it is right").

    python benchmarks/bench_confidence.py --root results [--split test] [--priors whole.json] [--out DIR]
        [--every 1] [--skip-simulated] [--today] [--city-calibration results/city/calibration.json]

Fits the solver's learned priors on the training split and the answers' calibration on the
validation split, as rule solver_priors does (or reads ``--priors``, a results/solver/priors/whole.json),
then measures every row of the issue's targets once on ``--split``: the scene map (each scene's
whole map), the tiled city of 20 scenes and the simulated city of 100,000 objects, with 1 and 5
frames and a 25 m GPS fix, through the entry functions of rules beyond_scene and beyond_city
(flatlandia.sequences.evaluation). Prints the targets table (measured, target, the issue's figure of
today) and every row's answers; writes the per-anchor rows (``errors.parquet``: probability,
answered, errors) and the fitted priors to ``--out``. ``--today``: the same rows with the solver of
before the issue (no likelihood ratio, no frames' answers) beside, its `confidence` as the
ranking of the answerable shares. ``--city-calibration``: rule city_calibration's map-size
correction, applied to the city rows' answers as rules beyond_city and city_eval do. Every row's
calibration error is printed beside its floor: the median ECE of a perfectly calibrated probability
on the same answers (outcomes drawn from the probabilities themselves, 200 draws), the error the
number of anchors alone leaves. CPU: one core, per query (a sequence: all its frames).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fine_solver import load  # noqa: E402

from flatlandia import config  # noqa: E402
from flatlandia.benchmark import metrics  # noqa: E402
from flatlandia.city import index, tiling  # noqa: E402
from flatlandia.sequences import evaluation as be  # noqa: E402
from flatlandia.sequences import validation  # noqa: E402
from flatlandia.solver import calibration, learned_priors  # noqa: E402

#: (row, map, frames, GPS sigma, figure, target, today: the issue's measurement of main)
TARGETS = [
    ("scene map, 1 frame, all answered: % within (5 m, 5°)", "scene", 1, None, "within_5m_5deg", ">= 70", "61.4"),
    ("scene map, 5 frames, all answered: % within (5 m, 5°)", "scene", 5, None, "within_5m_5deg", ">= 90", "77.2"),
    ("scene map, 1 frame: share answerable at >= 95 % within", "scene", 1, None, "answerable_95_pct", ">= 60", "20"),
    ("city-20, 1 frame: share answerable at <= 1 % wrong scene", "city-20", 1, None, "answerable_wrong_1pct", ">= 50", "5.6"),
    ("city-20, 5 frames: share answerable at <= 1 % wrong scene", "city-20", 5, None, "answerable_wrong_1pct", ">= 85", "(20.9 % wrong at 100 %)"),
    ("simulated 100,000, 5 frames: share answerable at <= 2 % wrong scene", "simulated-100000", 5, None, "answerable_wrong_2pct", ">= 50", "(60 % wrong at 100 %)"),
    ("calibration, scene map, 1 frame: ECE (10 bins), points", "scene", 1, None, "ece_points", "<= 5", ""),
    ("CPU per query, 1 frame, scene, median ms", "scene", 1, None, "cpu_median_ms", "<= 10", "4-9"),
    ("CPU per query, 5 frames, scene, median ms", "scene", 5, None, "cpu_median_ms", "<= 100", "35-66"),
    ("CPU per query, 5 frames, city-20, median ms", "city-20", 5, None, "cpu_median_ms", "<= 300", "107-173"),
    ("25 m GPS fix, 1 frame, city-20: % wrong scene", "city-20", 1, 25.0, "wrong_scene_pct", "0", "0"),
    ("25 m GPS fix, 1 frame, simulated 100,000: % wrong scene", "simulated-100000", 1, 25.0, "wrong_scene_pct", "0", "0"),
]  # fmt: skip

#: the settings of the solver of before this issue (its ranking, no frames' answers)
TODAY = {"solver": {"likelihood_weight": 0.0}, "sequence": {"frame_answers": 0}}


def priors(
    scenes, solver_cfg: dict, beyond: dict, seed: int, path: Path | None, out: Path
) -> learned_priors.LearnedPriors:
    """The learned priors of the whole map, fitted and calibrated as rule solver_priors does, or read."""
    if path is not None:
        return learned_priors.LearnedPriors.read(path)
    c0 = time.process_time()
    fitted = learned_priors.fit(scenes, solver_cfg, "whole")
    fitted, answers = validation.calibrated(scenes, solver_cfg, fitted, "whole", beyond, seed)
    print(f"priors fitted (train) and calibrated (val, {len(answers)} answers) in {time.process_time() - c0:.0f} s CPU")
    fitted.write(out / "whole.json")
    return fitted


def measure(named, solver_cfg, beyond, search, simulate, spacing, lp, seed, split, every, skip_simulated, log):
    """Per-anchor rows of every map and setting of :data:`TARGETS`."""
    scenes = [(r, q) for _, r, q in named]
    grid = [be.Setting(1), be.Setting(5), be.Setting(1, 25.0)]
    parts = []
    c0 = time.process_time()
    parts.append(be.scene_errors(scenes, grid, solver_cfg, beyond, lp, seed, split, every))
    log(f"scene rows: {time.process_time() - c0:.0f} s CPU")
    ref, q = tiling.tile([r for r, _ in scenes], [x for _, x in scenes], spacing)
    ref, q = ref.assign(city=0), q.assign(city=0)
    ix = index.build(ref, q[q["split"] == "train"])
    c0 = time.process_time()
    parts.append(
        be.tiled_city_errors(ref, q, lambda c: ix, grid, solver_cfg, search, beyond, lp, seed, split, "city-20", every)
    )
    log(f"city-20 rows: {time.process_time() - c0:.0f} s CPU")
    if not skip_simulated:
        names = [s for s, _, _ in named]
        refs = {s: r for s, r, _ in named}
        qs = {s: x for s, _, x in named}
        c0 = time.process_time()
        parts.append(
            be.simulated_city_errors(
                names, refs, qs, 100_000, simulate, spacing, grid, solver_cfg, search, beyond, lp, seed, split, every
            )
        )
        log(f"simulated-100000 rows: {time.process_time() - c0:.0f} s CPU")
    return pd.concat(parts, ignore_index=True)


def summaries(errors: pd.DataFrame) -> dict:
    """(map, frames, GPS sigma) -> summary (flatlandia.sequences.evaluation.summary)."""
    out = {}
    key = errors["gps_sigma_m"].fillna(-1.0)
    for (m, k, g), e in errors.groupby(["map", "frames", key]):
        out[(str(m), int(k), None if g < 0 else float(g))] = be.summary(e)
    return out


def ece_floor(probability, bins: int = 10, draws: int = 200, seed: int = 0) -> float:
    """The median ECE (points) of answers whose outcomes are drawn from ``probability`` itself: what
    a perfectly calibrated probability scores on this many answers."""
    p = np.asarray(probability, float)
    rng = np.random.default_rng(seed)
    return float(
        np.median([calibration.expected_calibration_error(p, rng.random(len(p)) < p, bins) for _ in range(draws)])
    )


def with_confidence(errors: pd.DataFrame) -> pd.DataFrame:
    """Today's ranking of the answers: `confidence` as the probability (the issue's measurement)."""
    return errors.assign(probability=errors["confidence"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("results"))
    ap.add_argument("--split", default="test")
    ap.add_argument("--priors", type=Path, default=None, help="a whole.json to use instead of fitting one")
    ap.add_argument("--out", type=Path, default=Path("bench_confidence"))
    ap.add_argument("--every", type=int, default=1, help="every n-th anchor of each scene")
    ap.add_argument("--skip-simulated", action="store_true")
    ap.add_argument("--today", action="store_true", help="also the solver of before the issue")
    ap.add_argument("--city-calibration", type=Path, default=None, help="rule city_calibration's record")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    cfg = config.resolve({})
    beyond = {k: v for k, v in cfg["beyond"].items() if k not in ("city_scenes", "city_objects")}
    named = load(args.root)
    scenes = [(r, q) for _, r, q in named]
    print(f"{len(named)} scenes from {args.root}; split {args.split}")
    t0, c0 = time.perf_counter(), time.process_time()
    lp = priors(scenes, cfg["solver"], beyond, cfg["seed"], args.priors, args.out)
    if args.city_calibration is not None:
        lp = lp.with_map_size(learned_priors.read_map_size(args.city_calibration))
        print(f"map-size correction: {lp.calibration.map_size}")
    runs = {"ours": (cfg["solver"], beyond, lp)}
    if args.today:
        old_beyond = {**beyond, "sequence": {**beyond["sequence"], **TODAY["sequence"]}}
        runs["today"] = ({**cfg["solver"], **TODAY["solver"]}, old_beyond, lp)
    results = {}
    for name, (solver_cfg, seq_beyond, fitted) in runs.items():
        errors = measure(
            named,
            solver_cfg,
            seq_beyond,
            cfg["city"]["search"],
            cfg["city"]["simulate"],
            float(cfg["city"]["spacing_m"]),
            fitted,
            cfg["seed"],
            args.split,
            args.every,
            args.skip_simulated,
            lambda m, name=name: print(f"[{name}] {m}", flush=True),
        )
        errors.to_parquet(args.out / f"errors_{name}.parquet")
        results[name] = summaries(errors if name == "ours" else with_confidence(errors))
    print(f"\nall rows in {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU (one process)\n")
    heads = ["case", "target", "today (issue)", "measured"] + (["today, same run (confidence)"] if args.today else [])
    print("| " + " | ".join(heads) + " |\n|" + "---|" * len(heads))
    for label, m, k, g, col, target, today in TARGETS:
        cells = [label, target, today]
        for name in runs:
            s = results[name].get((m, k, g))
            cells.append("–" if s is None or not np.isfinite(s[col]) else f"{s[col]:.1f}")
        print("| " + " | ".join(cells) + " |")
    print("\nevery row (ours):")
    cols = ["within_5m_5deg", "wrong_scene_pct", *metrics.ANSWER_COLUMNS, "cpu_median_ms", "cpu_p90_ms"]
    print("map | frames | GPS | " + " | ".join(cols) + " | ECE floor")
    ours = pd.read_parquet(args.out / "errors_ours.parquet")
    key = ours["gps_sigma_m"].fillna(-1.0)
    floors = {
        (str(m), int(k), None if g < 0 else float(g)): ece_floor(e["probability"])
        for (m, k, g), e in ours.groupby(["map", "frames", key])
    }
    for (m, k, g), s in sorted(results["ours"].items(), key=lambda x: (x[0][0], x[0][1], x[0][2] or 0)):
        print(f"{m} | {k} | {g or ''} | " + " | ".join(f"{s[c]:.1f}" for c in cols) + f" | {floors[(m, k, g)]:.1f}")
    one = ours[(ours["map"] == "scene") & (ours["frames"] == 1) & ours["gps_sigma_m"].isna()]
    within = (one["error_m"] < 5) & (one["error_deg"] < 5)
    bins = np.minimum((one["probability"].to_numpy() * 10).astype(int), 9)
    print("\nreliability, scene map, 1 frame (probability bin: answers, mean probability, % within):")
    for b in range(10):
        sel = bins == b
        if sel.any():
            print(
                f"  {b / 10:.1f}-{(b + 1) / 10:.1f}: {sel.sum()}, {one['probability'][sel].mean():.2f}, {100 * within[sel].mean():.1f}"
            )
    print(f"ECE {calibration.expected_calibration_error(one['probability'], within):.1f} points")
    json.dump(
        {f"{m}|{k}|{g}": s for (m, k, g), s in results["ours"].items()},
        open(args.out / "summaries.json", "w"),
        indent=1,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
