"""The audit as text, beside the records it reads (:mod:`provenance`): the records a run folder's
audit reads (:func:`audit_records`), one artifact's rule, settings, code and inputs
(:func:`audit_artifact`), the changed artifacts of ``--check`` (:func:`changed_report`) and the
table of every artifact (:func:`artifact_table`). ``flatlandia audit`` prints them
(flatlandia.commands.audit_command). Names and values come from files anyone can edit, so every line
is escaped for the terminal (:func:`escape.terminal`)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from flatlandia.plumbing import escape, provenance


def audit_records(provenance_dir: str | Path, manifest: str | Path, warn: Callable[[str], None]) -> pd.DataFrame:
    """The live provenance records (they describe the latest run, whatever its target), without
    those of outputs since deleted; the manifest is the fallback for a results folder copied
    without its logs. A broken record, a bad manifest row and an artifact outside the run's folder
    are each said through ``warn``, and the others audited; InputError when the manifest is not one."""
    skipped: list[str] = []
    df = provenance.manifest(provenance_dir, skipped)
    for line in skipped:  # a broken or tampered record: said, and the others audited
        warn(str(line))
    if not df.empty:
        df = df[[Path(a).exists() for a in df["artifact"]]]
    path = Path(manifest)
    if df.empty and path.exists():  # checked row by row: a copied manifest is as easily edited as a record
        skipped = []
        df = provenance.read_manifest(path, skipped)
        for line in skipped:
            warn(line)
    if not df.empty:  # only what lies inside this run's folder is ever hashed
        inside = [provenance.in_run(a) for a in df["artifact"]]
        for a in df.loc[[not i for i in inside], "artifact"]:
            warn(f"{str(a)[:200]}: an artifact outside the run's folder, left out of the audit")
        df = df[inside]
    return df


def _short(digest: str) -> str:
    return str(digest or "")[:12]


def _flat(d: dict, prefix: str = "") -> dict:
    """Nested settings as dotted keys, one value each."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        out.update(_flat(v, key) if isinstance(v, dict) and v else {key: v})
    return out


def run_relative(artifact: str) -> str:
    """An artifact as the records name it: relative to the run's folder (the working folder), also
    when given as an absolute path inside it (a shell's completion, a file manager's copy)."""
    path = Path(artifact)
    if path.is_absolute() or ".." in path.parts or path.is_symlink() or any(p.is_symlink() for p in path.parents):
        try:  # resolved: results/../results/x and a link into results/ name the record's artifact
            path = path.resolve().relative_to(Path.cwd().resolve())
        except (OSError, ValueError):  # outside the run's folder: no record names it
            pass
    return str(path)


def audit_artifact(df: pd.DataFrame, artifact: str, tree: bool, configs: Path) -> str:
    """What produced one artifact, as text: rule, settings by value, inputs and their rules (each line
    escaped for the terminal: :func:`escape.terminal`); empty when no record names it."""
    rows = provenance.producers(df)
    rec = rows.get(artifact)
    if rec is None:
        return ""
    now, _ = provenance.path_digest(artifact)
    lines = [
        f"artifact: {artifact}",
        f"  sha256 {_short(rec['sha256'])}, {int(rec['bytes']):,} bytes, "
        + ("the file matches its record" if now == rec["sha256"] else "CHANGED since the run wrote it"),
        f"rule: {rec['rule']}" + (f"  (wildcards {rec['wildcards']})" if rec["wildcards"] not in ("{}", "") else ""),
        f"settings the rule reads (hash {rec['config_hash']}):",
    ]
    settings = json.loads(rec.get("settings") or "{}")
    lines += [f"  {k}: {json.dumps(v, default=str)}" for k, v in _flat(settings).items()] or ["  (none)"]
    if rec.get("config_id"):
        lines.append(f"whole resolved config: {configs / (rec['config_id'] + '.json')}")
    dirty = rec.get("dirty")
    lines.append(
        f"code: commit {rec['git_commit'].removesuffix('+dirty')}"
        + (" with uncommitted changes" if dirty else " (clean)" if dirty is False else "")
        + f", flatlandia {rec['package_version']}"
    )
    sheet = json.loads(rec.get("scene_sheet") or "{}")
    if sheet.get("path"):
        lines.append(f"scene sheet: {sheet['path']} (sha256 {_short(sheet.get('sha256', ''))})")
    software = json.loads(rec.get("software") or "{}")
    if software:
        lines.append("software: " + ", ".join(f"{k} {v}" for k, v in software.items()))
    if rec.get("started_at"):
        lines.append(
            f"time: {rec['started_at']} to {rec['finished_at']}, "
            f"{rec.get('wall_seconds', float('nan')):.1f} s wall, {rec.get('cpu_seconds', float('nan')):.1f} s CPU"
        )
    lines.append("inputs" + (" (back to the files no rule produced: the sources)" if tree else "") + ":")
    if tree:  # each subtree once, shared ones referred back to
        lines += ["  " * depth + text for depth, text in provenance.lineage_tree(artifact, df)]
    else:
        for inp in provenance.lineage(artifact, df, tree):
            pad = "  " * inp["depth"]
            made = f"<- {inp['rule']}" if inp["rule"] else "(source)"
            flag = "  CHANGED since used" if inp["changed"] else ""
            lines.append(f"{pad}{inp['input']}  {_short(inp['sha256'])}  {made}{flag}")
    return "\n".join(escape.terminal(line) for line in lines)  # each line of names and values from records


def changed_report(df: pd.DataFrame, bad: pd.DataFrame) -> str:
    """``--check``'s text when artifacts changed (``bad``, :func:`provenance.check` of ``df``): how
    many, then each with its rule and its recorded and current sha256."""
    lines = [f"{len(bad)} of {len(df)} recorded artifacts changed since their rule wrote them:"]
    for r in bad.itertuples(index=False):
        line = f"  {r.artifact} (rule {r.rule}): recorded {_short(r.recorded)}, now {_short(r.now)}"
        lines.append(escape.terminal(line))
    return "\n".join(lines)


def artifact_table(df: pd.DataFrame) -> str:
    """Every recorded artifact, one row each: its rule, sha256, size, settings' hash, commit and time."""
    cols = ["artifact", "rule", "sha256", "bytes", "config_hash", "git_commit", "finished_at"]
    with pd.option_context("display.max_rows", None, "display.max_colwidth", 64, "display.width", 250):
        out = df[cols].assign(sha256=df["sha256"].str[:12])
        out = out.map(lambda v: escape.terminal(v) if isinstance(v, str) else v)  # names from the records
        return out.to_string(index=False)
