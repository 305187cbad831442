"""How fast `flatlandia localize` starts: the first call ever (numba compiles every solver kernel into
its cache) and the calls after it (the kernels loaded from the cache), as whole processes.

    python benchmarks/bench_fast_start.py --results results [--scene 12] [--runs 3]

The first call runs with an empty numba cache folder of its own (NUMBA_CACHE_DIR, as a fresh or a
read-only install would have: numba then caches under the user's cache folder); the later calls
reuse it. Prints wall and CPU seconds of each call, and the import time of the command's modules
(``python -X importtime``, the ten slowest top-level packages).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from flatlandia.classes import CLASSES  # noqa: E402

FLATLANDIA = str(Path(sys.executable).parent / "flatlandia")


def query_file(results: Path, scene: str, out: Path) -> Path:
    """A test query of ``scene`` as a localizer query file (its depth local map)."""
    q = pd.read_parquet(results / scene / "queries/queries.parquet")
    r = q[q["split"] == "test"].iloc[0]
    objects = [
        {"class": CLASSES[c], "x": float(x), "y": float(y)} for c, (x, y) in zip(r["classes"], r["depth_local_xy"])
    ]
    out.write_text(json.dumps({"objects": objects}))
    return out


def timed(cmd: list[str], env: dict) -> tuple[float, float]:
    """(wall, CPU seconds) of a child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise SystemExit(f"ERROR: {' '.join(cmd)} failed: {res.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def import_times(env: dict) -> list[tuple[int, str]]:
    res = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", "import flatlandia.cli, flatlandia.solver, flatlandia.localize"],
        env=env,
        capture_output=True,
        text=True,
    )
    out = []
    for line in res.stderr.splitlines():
        parts = [p.strip() for p in line.split("|")]
        if len(parts) == 3 and parts[1].isdigit() and "." not in parts[2] and not parts[2].startswith(" "):
            out.append((int(parts[1]), parts[2]))
    return sorted(out, reverse=True)[:10]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--scene", default="12")
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba")}
        q = query_file(a.results, a.scene, Path(tmp) / "q.json")
        cmd = [FLATLANDIA, "localize", "--map", str(a.results / a.scene / "maps/reference_map.parquet")]
        cmd += ["--query", str(q), "--map-type", "depth"]
        wall, cpu = timed(cmd, env)
        print(f"first call (empty cache): {wall:.2f} s wall, {cpu:.2f} s CPU")
        for k in range(a.runs):
            wall, cpu = timed(cmd, env)
            print(f"call {k + 2} (cached kernels): {wall:.2f} s wall, {cpu:.2f} s CPU")
        print("imports (ms, top-level packages): " + ", ".join(f"{n} {us / 1000:.0f}" for us, n in import_times(env)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
