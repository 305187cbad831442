"""A run folder that travels: copied or moved, into another clone of the same commit, it plans nothing.

Why: Snakemake reruns a script rule whose outputs are older than its script, and any job whose
inputs are newer than its outputs. A finished run copied into another clone (whose scripts were
checked out after the run) or copied without its times (``cp -r``: every file as new as the copy,
in the copy's order) planned 212 of its 247 jobs again ("Code has changed since last execution").
Its content, code and settings were the same: only the times told otherwise.

So when the Snakefile is read in a run folder that was last run elsewhere (:data:`HOME` records
where), :func:`settle` checks each finished job by its provenance record
(:mod:`flatlandia.plumbing.provenance`) and, where everything it can check agrees, gives its outputs
new times in the order the jobs ran, all newer than this clone's workflow files (what
``snakemake --touch`` does, but only for jobs whose content is shown to be what was built):

- every output still has the sha256 its record holds, and every input the one it was read with;
- the record's workflow commit is this clone's, or differs from it in nothing under ``workflow/``
  (``git diff``), and neither had uncommitted changes there.

A job that fails a check keeps its times: Snakemake then reruns it as it would have, and the run's
start says how many and why (:mod:`flatlandia.plumbing.rerun_notice`). Its settings are not checked
here: Snakemake compares them with its own records (``.snakemake/metadata``, copied with the run).
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

from flatlandia.plumbing import provenance

#: where a run folder records the folder it last ran in and the workflow it ran
HOME = Path(".snakemake/flatlandia_home.json")
#: where the rules' ``benchmark:`` files lie: Snakemake takes a job's oldest output *or benchmark
#: file* as the time its inputs must not be newer than, so they are re-timed after every output
BENCHMARKS = Path("logs/benchmarks")
#: the workflow's own files: outputs are made newer than every one of them
WORKFLOW_FILES = ("scripts", "rules", "Snakefile", "flatlandia", "schemas")


def here(workflow_dir: str | Path | None) -> dict:
    """This run folder and workflow, as :data:`HOME` records them."""
    return {
        "run_folder": str(Path.cwd().resolve()),
        "workflow": str(Path(workflow_dir).resolve()) if workflow_dir else None,
    }


def _read_home() -> dict | None:
    try:
        d = json.loads(HOME.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _write_home(record: dict) -> None:
    try:
        HOME.parent.mkdir(parents=True, exist_ok=True)
        tmp = HOME.with_suffix(".tmp")
        tmp.write_text(json.dumps(record))
        os.replace(tmp, HOME)
    except OSError:
        pass  # a read-only run folder: nothing to record, nothing to settle next time either


def _git(folder: str, *args: str) -> subprocess.CompletedProcess | None:
    try:
        return subprocess.run(["git", "-C", folder, *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None


def same_code(workflow_dir: str, commits: set[str]) -> dict[str, bool]:
    """Per recorded commit, whether this clone's ``workflow/`` folder holds the same files: the same
    commit, or one whose ``workflow/`` does not differ from it, with no uncommitted change in it."""
    out = dict.fromkeys(commits, False)
    repo = str(Path(workflow_dir).parent)
    head = _git(repo, "rev-parse", "HEAD")
    status = _git(repo, "status", "--porcelain", "--untracked-files=no", "--", "workflow")
    if head is None or head.returncode != 0 or status is None or status.stdout.strip():
        return out
    for c in commits:
        if c == head.stdout.strip():
            out[c] = True
        elif c and c != "unknown":
            diff = _git(repo, "diff", "--quiet", c, "HEAD", "--", "workflow")
            out[c] = diff is not None and diff.returncode == 0
    return out


def _digest(path: str, cache: dict[str, str]) -> str:
    if path not in cache:
        cache[path] = provenance.path_digest(path)[0] if os.path.exists(path) else ""
    return cache[path]


def checked_records(workflow_dir: str, records: list[dict]) -> tuple[list[dict], dict[str, int]]:
    """(the records whose outputs, inputs and code are as built, why the others are not: a count
    per reason)."""
    code = same_code(workflow_dir, {str(r.get("workflow", {}).get("commit", "")) for r in records})
    digests: dict[str, str] = {}
    good, why = [], {}

    def reject(reason: str) -> None:
        why[reason] = why.get(reason, 0) + 1

    for rec in records:
        state = rec.get("workflow") or {}
        if state.get("dirty") or not code.get(str(state.get("commit", "")), False):
            reject("built by other code")
        elif any(_digest(p, digests) != o.get("sha256") for p, o in rec["outputs"].items()):
            reject("an output differs from what was built")
        elif any(_digest(p, digests) != h for p, h in rec.get("inputs", {}).items()):
            reject("an input differs from what it was built from")
        else:
            good.append(rec)
    return good, why


def in_order(records: list[dict]) -> list[dict]:
    """``records`` with each after the records that made its inputs (their order of finishing,
    which a copied run keeps in its records, breaks ties)."""
    made = {p: k for k, r in enumerate(records) for p in r["outputs"]}
    order, state = [], {}

    def visit(k: int) -> None:
        if state.get(k) == 2:
            return
        if state.get(k) == 1:  # a loop in tampered records: stop following it
            return
        state[k] = 1
        for p in records[k].get("inputs", {}):
            if p in made and made[p] != k:
                visit(made[p])
        state[k] = 2
        order.append(records[k])

    for k in sorted(range(len(records)), key=lambda k: str(records[k].get("finished_at", ""))):
        visit(k)
    return order


def newest_workflow_file(workflow_dir: str) -> float:
    """The newest modification time of the workflow's own files."""
    newest = 0.0
    for name in WORKFLOW_FILES:
        p = Path(workflow_dir) / name
        paths = p.rglob("*") if p.is_dir() else [p]
        for q in paths:
            try:
                newest = max(newest, q.stat().st_mtime)
            except OSError:
                continue
    return newest


def retime(records: list[dict], start: float) -> int:
    """Give the outputs of ``records`` (in order) times from ``start`` up, a millisecond apart; a
    folder output its timestamp file too. The number of outputs."""
    n = 0
    for k, rec in enumerate(records):
        t = start + k * 1e-3
        for p in rec["outputs"]:
            for q in (p, os.path.join(p, ".snakemake_timestamp")):
                if os.path.exists(q):
                    os.utime(q, (t, t), follow_symlinks=False)
            n += 1
    return n


def retime_benchmarks(t: float) -> int:
    """Give every benchmark file (:data:`BENCHMARKS`) the time ``t``, after every re-timed output:
    a benchmark file older than a job's re-timed inputs would plan the job again (``Updated input
    files``), and a later one changes nothing (Snakemake takes the oldest of outputs and benchmark).
    The number of files."""
    n = 0
    for q in BENCHMARKS.rglob("*") if BENCHMARKS.is_dir() else []:
        if q.is_file() and not q.is_symlink():
            os.utime(q, (t, t))
            n += 1
    return n


def settle(workflow_dir: str | None, log: Callable[[str], None] = print) -> str | None:
    """Where this run folder was last run elsewhere (:data:`HOME`), give the outputs of every job
    whose record checks out (:func:`checked_records`) new times in the order they were built; one
    line saying what was done (None: nothing to do). Records this folder as the run's home."""
    now = here(workflow_dir)
    old = _read_home()
    if old == now or workflow_dir is None or not Path(workflow_dir).is_dir():
        return None
    records = provenance.records()
    if not records:
        _write_home(now)
        return None
    t0 = time.perf_counter()
    good, why = checked_records(str(workflow_dir), records)
    start = max(time.time(), newest_workflow_file(str(workflow_dir))) + 1.0
    n = retime(in_order(good), start)
    retime_benchmarks(start + len(good) * 1e-3 + 1e-3)
    _write_home(now)
    came = f"from {old['run_folder']}" if old and old.get("run_folder") else "from elsewhere (no record of where)"
    others = "; ".join(f"{v} {k}" for k, v in sorted(why.items())) or "none"
    line = (
        f"this run folder was last run {came}: {len(good)} of {len(records)} jobs checked by their provenance "
        f"records (content and code as built) and their {n} outputs re-timed in build order; not re-timed: "
        f"{others} ({time.perf_counter() - t0:.1f} s)"
    )
    log(line)
    return line
