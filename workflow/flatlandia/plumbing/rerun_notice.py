"""Say, before the first job, which existing results a run is about to redo, and why.

Why: a changed setting (``--configfile my.yaml``, ``config/paper.yaml``) reruns every job that
reads it, in place, over the results of the earlier config: dozens of jobs and hours of training
overwritten without a word. The Snakefile's ``onstart`` hands the jobs Snakemake will run (with
its reasons) to :func:`notice`, which counts those whose outputs exist and were built by other
settings or code, names the config keys that changed (from the provenance records' stored
configs) and suggests a folder of its own (``-d runs/<name>``). It only informs: the run goes on.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from flatlandia.plumbing import provenance


@dataclass(frozen=True)
class PlannedJob:
    """A job Snakemake will run: its rule, outputs, and why (Snakemake's reasons, as flags)."""

    rule: str
    outputs: tuple[str, ...]
    params_changed: bool = False
    code_changed: bool = False
    input_changed: bool = False
    forced: bool = False
    reason: str = ""  # Snakemake's reasons, as it words them


def from_dag(dag) -> list[PlannedJob]:
    """The jobs of a Snakemake DAG that will run, with their reasons (Snakemake's internal API:
    an empty list, and so no notice, if it changes)."""
    try:
        jobs = list(dag.needrun_jobs())
        out = []
        for job in jobs:
            reason = dag.reason(job)
            out.append(
                PlannedJob(
                    job.rule.name,
                    tuple(str(o) for o in job.output),
                    bool(reason.params_changed),
                    bool(reason.code_changed),
                    bool(reason.input_changed),
                    bool(reason.forced),
                    str(reason),
                )
            )
        return out
    except (AttributeError, TypeError):
        return []


def _flatten(d, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def changed_keys(old: dict, new: dict, ignore: Iterable[str] = ("select",)) -> list[str]:
    """Dotted config keys whose values differ between two resolved configs, as 'key: old -> new'."""
    a, b = _flatten(old), _flatten(new)
    skip = tuple(ignore)
    keys = sorted(k for k in set(a) | set(b) if not k.startswith(skip) and a.get(k) != b.get(k))
    return [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in keys]


def redo_line(jobs: list[PlannedJob]) -> str | None:
    """One line: how many jobs redo results that exist here, by rule, and the first reasons
    (Snakemake's words: an input updated, code or settings changed, forced...); None when none does."""
    redo = [j for j in jobs if any(Path(o).exists() for o in j.outputs)]
    if not redo:
        return None
    by_rule = Counter(j.rule for j in redo)
    reasons = Counter(j.reason.split(";")[0].strip() or "no reason given" for j in redo)
    return (
        f"flatlandia: this run redoes {len(redo)} of {len(jobs)} job(s) over results that exist here ("
        + ", ".join(f"{rule} {n}" for rule, n in by_rule.most_common(6))
        + (", ..." if len(by_rule) > 6 else "")
        + "); first reasons: "
        + "; ".join(f"{why} ({n})" for why, n in reasons.most_common(3))
    )


def notice(jobs: list[PlannedJob], config: dict, records_dir: str | Path = provenance.PROVENANCE_DIR) -> str | None:
    """The message for jobs that will overwrite existing results (:func:`redo_line`), and for those
    built with other settings or code what changed; None when no job redoes an existing result."""
    first = redo_line(jobs)
    redo = [j for j in jobs if any(Path(o).exists() for o in j.outputs) and (j.params_changed or j.code_changed)]
    if not redo:
        return first
    by_rule = Counter(j.rule for j in redo)
    why = Counter("settings" if j.params_changed else "code" for j in redo)
    lines = [
        first,
        f"flatlandia: {len(redo)} of them were built with other "
        f"{' and '.join(f'{k} ({n})' for k, n in why.items())}: "
        + ", ".join(f"{rule} {n}" for rule, n in by_rule.most_common())
        + "; their results will be replaced.",
    ]
    old_ids = _old_config_ids(redo, records_dir)
    if old_ids:
        old = provenance.stored_config(old_ids.most_common(1)[0][0], Path(records_dir) / "configs")
        if old is not None:
            diff = changed_keys(old, dict(config))
            if diff:
                shown = "; ".join(diff[:8]) + (f"; and {len(diff) - 8} more" if len(diff) > 8 else "")
                lines.append(f"flatlandia: config changed since those results were built: {shown}")
    if why.get("settings"):
        lines.append(
            "flatlandia: to keep them, stop now (Ctrl-C) and run this config in a folder of its own: "
            "snakemake -d runs/<name> ... (results, logs and models go under runs/<name>/)"
        )
    return "\n".join(lines)


def _old_config_ids(jobs: list[PlannedJob], records_dir: str | Path) -> Counter:
    """The stored-config ids of the records that wrote the outputs these jobs will replace."""
    wanted = {o for j in jobs for o in j.outputs}
    ids: Counter = Counter()
    for rec in provenance.records(records_dir):
        if wanted & set(rec["outputs"]) and rec.get("config_id"):
            ids[rec["config_id"]] += 1
    return ids
