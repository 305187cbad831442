"""``flatlandia audit [PATH]``: the audit trail of a run, one artifact (``--tree``: back to the
sources), one scene or all; ``--check`` re-hashes every recorded artifact, ``--write FILE`` writes
the records as a manifest. The text is :mod:`flatlandia.plumbing.audit_report`'s, beside the records."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from flatlandia.commands.messages import error, warning
from flatlandia.plumbing import audit_report, files, provenance
from flatlandia.plumbing.errors import InputError


def audit(args) -> int:
    """Print the audit the options ask for; exit status 1 after one ERROR line when there is nothing
    to audit, and after ``--check``'s list when an artifact changed."""
    try:
        df = audit_report.audit_records(args.provenance, args.manifest, warning)
    except InputError as e:  # the manifest fallback is not a manifest
        error(str(e))
        return 1
    if df.empty:
        error(
            f"no audit records in {Path.cwd()}: run flatlandia audit in the run's folder, or run the workflow "
            f"first ({args.manifest} and {args.provenance} are empty)"
        )
        return 1
    made_by = dict(zip(df["artifact"], df["rule"]))  # every recorded artifact, before --scene narrows df
    if args.check:  # every recorded artifact re-hashed, or the one named, or one scene's
        return _check(df, args)
    if args.artifact:
        return _audit_one(df, args)
    if args.scene:
        known = sorted(set(df["scene"].dropna().astype(str)) - {""})
        df = df[df["scene"] == args.scene]
        if df.empty:
            error(f"no audit records for scene {args.scene!r}; scenes with records: {', '.join(known)}")
            return 1
    if args.write:  # the manifest of any run, whatever its target (rule manifest comes with `all`)
        return _write_manifest(args, df, made_by)
    print(audit_report.artifact_table(df))
    print("\nflatlandia audit PATH shows one artifact's settings and inputs (--tree: back to the sources)")
    return 0


def _check(df: pd.DataFrame, args) -> int:
    """``--check``: re-hash the recorded artifacts (only ``PATH``'s, or ``--scene``'s, when given)
    and list those changed; 1 when one changed or nothing recorded matches what was named."""
    what = "recorded artifacts"
    if args.artifact:
        df = df[df["artifact"] == audit_report.run_relative(args.artifact)]
        what = f"recorded artifacts named {args.artifact}"
        if df.empty:
            error(
                f"{args.artifact}: no audit record (not an output of this run's rules, or built before records existed)"
            )
            return 1
    elif args.scene:
        df = df[df["scene"] == args.scene]
        what = f"recorded artifacts of scene {args.scene}"
        if df.empty:
            error(f"no audit records for scene {args.scene!r}")
            return 1
    bad = provenance.check(df)
    if bad.empty:
        print(
            f"{args.artifact} matches its record"
            if len(df) == 1 and args.artifact
            else f"all {len(df)} {what} match their records"
        )
        return 0
    print(audit_report.changed_report(df, bad))
    return 1


def _audit_one(df: pd.DataFrame, args) -> int:
    """``audit PATH``: what produced one artifact; one ERROR line naming recorded artifacts of the
    same file name when no record names it."""
    configs = Path(args.provenance) / "configs"
    text = audit_report.audit_artifact(df, audit_report.run_relative(args.artifact), args.tree, configs)
    if not text:
        near = [a for a in df["artifact"] if Path(a).name == Path(args.artifact).name][:5]
        error(
            f"{args.artifact}: no audit record (not an output of this run's rules, or built before "
            "records existed)" + (f"; recorded artifacts of that name: {', '.join(near)}" if near else "")
        )
        return 1
    print(text)
    return 0


def _write_manifest(args, df: pd.DataFrame, made_by: dict[str, str]) -> int:
    """``audit --write FILE``: the records as a manifest, through the write door
    (:func:`files.check_target`), never onto a file the audit reads (the manifest, the records) nor
    onto or into an artifact any record names (compared resolved: ``results/../results/x`` and a
    link to ``results/`` are the artifact itself): its manifest would break the run it audits."""
    named = {a: r["rule"] for r in provenance.records(args.provenance) for a in r["outputs"]} | made_by
    target = files.resolved(args.write)
    rule = next((r for a, r in named.items() if target.is_relative_to(os.path.realpath(a))), None)
    if rule is not None:
        error(f"--write {args.write}: an artifact of this run (rule {rule}): give a new file")
        return 1
    try:
        files.write_parquet(
            df.reset_index(drop=True), args.write, reads=[args.manifest, args.provenance], artifacts=named
        )
    except InputError as e:
        error(f"--write {e}")
        return 1
    except OSError as e:  # a full disk, a folder that cannot be made
        error(f"--write {args.write}: cannot be written ({e.strerror or e})")
        return 1
    print(f"wrote {args.write}: {len(df)} artifacts from {df['rule'].nunique()} rules")
    return 0
