"""``flatlandia localize`` on the published test queries: accuracy, time per query, start-up.

    python benchmarks/bench_localize.py --results results [--city results/city/20/index] [--out DIR]
    taskset -c 0 python benchmarks/bench_localize.py --results /tmp/run1/results --city <copy>/results/city/20/index

Every benchmark scene's test queries (``results/{scene}/queries/queries.parquet``) are written as
query files (``{"queries": [...]}``, :func:`flatlandia.localize.query_json`), read back through the
public path (:func:`flatlandia.localize.read_queries`) and localized on the scene's reference map as
the command does (:func:`flatlandia.localize.load_map` once per scene, then
:func:`flatlandia.localize.localize` per query), with GT local maps and with depth local maps.
Prints, per map type: % of queries within 0.5 m (and within 0.5 m and 2 deg), the median error,
and for depth maps whether every pose equals the benchmark's whole-map run
(``results/fine/solver_depth_whole/errors.parquet``: x, y, heading, matches) and its median against
the row of ``results/tables/fine_localization.parquet``; the time per query after loading (wall
and CPU of the process, median and p90) and the loading time per map. With ``--city``: the same
on a city index (its city's test queries, ``results/city/{n}/queries.parquet``, in the tiled
frame). Then the start-up: ``python -c 'import flatlandia.localize'`` and ``flatlandia localize
--help`` (median of ``--repeat`` runs), and one whole command on one query.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia import localize, paths  # noqa: E402
from flatlandia.data import localmaps  # noqa: E402
from flatlandia.geo import pose_errors  # noqa: E402


def write_queries(test: pd.DataFrame, map_type: str, path: Path) -> Path:
    """The test queries of one table as a query file (ids: tokens)."""
    doc = {
        "queries": [
            localize.query_json(localmaps.local_map(r, map_type), r.classes, str(r.token))
            for r in test.itertuples(index=False)
        ]
    }
    path.write_text(json.dumps(doc))
    return path


def run(map_path: Path, test: pd.DataFrame, map_type: str, folder: Path, name: str) -> tuple[pd.DataFrame, float]:
    """(per-query rows: errors, times, pose; the map's loading seconds) of one map's test queries."""
    queries, _ = localize.read_queries(write_queries(test, map_type, folder / f"{name}_{map_type}.json"))
    t0 = time.perf_counter()
    m = localize.load_map(map_path)
    load_s = time.perf_counter() - t0
    rows = []
    for q, r in zip(queries, test.itertuples(index=False)):
        t0, c0 = time.perf_counter(), time.process_time()
        out = localize.localize(m, q, map_type)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if out["found"]:
            e_m, e_deg = pose_errors(
                out["x_m"], out["y_m"], np.radians(out["theta_deg"]), r.x_m, r.y_m, np.radians(r.theta_deg)
            )
        else:
            e_m, e_deg = np.inf, 180.0
        matched = [-1] * len(q.cls)
        for mt in out["matches"]:
            matched[mt["query_object"]] = mt["obj_idx"]
        rows.append(
            {
                "scene": str(r.scene),
                "token": str(r.token),
                "error_m": float(e_m),
                "error_deg": float(e_deg),
                "x": out["x_m"],
                "y": out["y_m"],
                "theta_deg": out["theta_deg"],
                "matched": matched,
                "wall_ms": 1000 * wall,
                "cpu_ms": 1000 * cpu,
                "solver_ms": 1000 * out["seconds"],
            }
        )
    return pd.DataFrame(rows), load_s


def accuracy(e: pd.DataFrame) -> str:
    em, ed = e["error_m"].to_numpy(float), e["error_deg"].to_numpy(float)
    return (
        f"{len(e)} queries: {100 * np.mean(em < 0.5):.1f} % within 0.5 m, "
        f"{100 * np.mean((em < 0.5) & (ed < 2)):.1f} % within (0.5 m, 2 deg), "
        f"median {np.median(em):.3g} m / {np.median(ed):.3g} deg, no pose {100 * np.mean(~np.isfinite(em)):.1f} %"
    )


def timing(e: pd.DataFrame, loads: list[float]) -> str:
    w, c = e["wall_ms"], e["cpu_ms"]
    return (
        f"per query after loading: wall median {w.median():.2f} ms (p90 {w.quantile(0.9):.2f}), "
        f"CPU median {c.median():.2f} ms (p90 {c.quantile(0.9):.2f}); loading a map: "
        f"median {1000 * statistics.median(loads):.0f} ms, max {1000 * max(loads):.0f} ms"
    )


def same_as_benchmark(e: pd.DataFrame, results: Path) -> str:
    """Do the depth poses equal rule fine_eval's whole-map run, query by query?"""
    path = paths.within(results, paths.fine_run("solver", "depth", "whole"))
    if not path.exists():
        return f"(no {path} to compare with)"
    ref = pd.read_parquet(path).set_index(["scene", "token"])
    ref = ref.loc[list(zip(e["scene"], e["token"]))]
    pos = np.allclose(ref["x"], e["x"], rtol=0, atol=1e-9) and np.allclose(ref["y"], e["y"], rtol=0, atol=1e-9)
    d_theta = np.abs((ref["theta_deg"].to_numpy() - e["theta_deg"].to_numpy() + 180) % 360 - 180)
    matches = all(list(a) == list(b) for a, b in zip(ref["matched_obj_idx"], e["matched"]))
    errors = np.allclose(ref["error_m"], e["error_m"], rtol=0, atol=1e-9)
    table = paths.within(results, paths.table("fine_localization"))
    row = ""
    if table.exists():
        t = pd.read_parquet(table).set_index("run")
        if "solver_depth_whole" in t.index:
            row = f"; table row solver_depth_whole: median {t.loc['solver_depth_whole', 'median_m']:.4f} m"
    return (
        f"same poses as {path}: positions {pos}, headings {bool(d_theta.max() < 1e-9)}, matches {matches}, "
        f"errors {errors} (median here {np.median(e['error_m']):.4f} m{row})"
    )


def startup(repeat: int, map_path: Path, query: Path) -> list[str]:
    """Median seconds of the interpreter's start-up with the module, of the command's --help and of
    a whole command on one query."""
    exe = Path(sys.executable)
    cli = exe.with_name("flatlandia")
    cmds = {
        "python -c 'import flatlandia.localize'": [str(exe), "-c", "import flatlandia.localize"],
        "python -c pass (the interpreter alone)": [str(exe), "-c", "pass"],
        "flatlandia localize --help": [str(cli), "localize", "--help"],
        f"flatlandia localize --map {map_path.name} --query (one query)": [
            str(cli),
            "localize",
            "--map",
            str(map_path),
            "--query",
            str(query),
        ],
    }
    lines = []
    for name, cmd in cmds.items():
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
        lines.append(f"  {name}: median {statistics.median(times):.2f} s over {repeat}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results", help="a finished run's results folder")
    ap.add_argument("--city", help="a city index (results/city/{n}/index or one .npz)")
    ap.add_argument("--map-types", nargs="+", default=["gt", "depth"])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each start-up command")
    ap.add_argument("--out", help="write the per-query rows here (Parquet per map type)")
    args = ap.parse_args()
    results = Path(args.results)
    scenes = sorted((p.name for p in results.iterdir() if p.name.isdigit()), key=int)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for map_type in args.map_types:
            parts, loads = [], []
            for s in scenes:
                q = pd.read_parquet(results / s / "queries" / "queries.parquet")
                test = q[q["split"] == "test"]
                if len(test):
                    e, load_s = run(results / s / "maps" / "reference_map.parquet", test, map_type, folder, s)
                    parts.append(e)
                    loads.append(load_s)
            e = pd.concat(parts, ignore_index=True)
            print(f"scene maps, {map_type} local maps ({len(scenes)} scenes): {accuracy(e)}")
            print(f"  {timing(e, loads)}")
            if map_type == "depth":
                print(f"  {same_as_benchmark(e, results)}")
            if args.out:
                Path(args.out).mkdir(parents=True, exist_ok=True)
                e.to_parquet(Path(args.out) / f"scenes_{map_type}.parquet")
        if args.city:
            city = Path(args.city)
            npz = city if city.suffix == ".npz" else sorted(city.glob("*.npz"))[0]
            cq = pd.read_parquet(npz.parent.parent / "queries.parquet")
            cq = cq[(cq["city"].astype(str) == npz.stem) & (cq["split"] == "test")]
            for map_type in args.map_types:
                e, load_s = run(npz, cq, map_type, folder, "city")
                print(f"city index {npz} ({map_type} local maps): {accuracy(e)}")
                print(f"  {timing(e, [load_s])}")
                if args.out:
                    e.to_parquet(Path(args.out) / f"city_{map_type}.parquet")
        one = folder / "one.json"
        first = scenes[0]
        q = pd.read_parquet(results / first / "queries" / "queries.parquet")
        r = q[q["split"] == "test"].iloc[0]
        one.write_text(json.dumps(localize.query_json(localmaps.local_map(r, "gt"), r.classes)))
        print("start-up (interpreter and imports, no query):")
        for line in startup(args.repeat, results / first / "maps" / "reference_map.parquet", one):
            print(line)


if __name__ == "__main__":
    main()
