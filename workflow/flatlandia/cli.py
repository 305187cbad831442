"""Command line: ``flatlandia audit`` prints the audit trail of a run (one scene or all);
``flatlandia config`` checks or rewrites the files generated from the config schema."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from flatlandia import config, io, provenance


def audit(args) -> int:
    path = Path(args.manifest)
    # the live provenance records describe the latest run, whatever its target; the manifest is
    # the fallback for a results folder copied without its logs
    df = provenance.manifest(args.provenance)
    if not df.empty:
        df = df[[Path(a).exists() for a in df["artifact"]]]  # records of outputs since deleted
    if df.empty and path.exists():
        df = pd.read_parquet(path)
    if df.empty:
        print(f"ERROR: no audit records: run the workflow first ({path} and {args.provenance} are empty)")
        return 1
    if args.scene:
        known = sorted(set(df["scene"].dropna().astype(str)) - {""})
        df = df[df["scene"] == args.scene]
        if df.empty:
            print(f"ERROR: no audit records for scene {args.scene!r}; scenes with records: {', '.join(known)}")
            return 1
    if args.write:  # the manifest of any run, whatever its target (rule manifest comes with `all`)
        io.write_parquet(df.reset_index(drop=True), args.write)
        print(f"wrote {args.write}: {len(df)} artifacts from {df['rule'].nunique()} rules")
        return 0
    cols = ["artifact", "rule", "sha256", "bytes", "config_hash", "git_commit", "finished_at"]
    with pd.option_context("display.max_rows", None, "display.max_colwidth", 64, "display.width", 250):
        out = df[cols].assign(sha256=df["sha256"].str[:12])
        print(out.to_string(index=False))
    return 0


def config_files(args) -> int:
    """Rewrite (``--write``) or check config/config.yaml and config/README.md against the schema."""
    stale = []
    for path, text in config.generated_files(Path(args.repo)).items():
        if path.exists() and path.read_text() == text:
            continue
        if args.write:
            path.write_text(text)
            print(f"wrote {path}")
        else:
            stale.append(str(path))
    if stale:
        print(f"ERROR: {', '.join(stale)} out of date with {config.SCHEMA_PATH}: run `flatlandia config --write`")
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="flatlandia", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("audit", help="print which rule, inputs, config and commit produced each artifact")
    a.add_argument("--scene", help="only this scene's artifacts")
    a.add_argument("--manifest", default="results/manifest.parquet")
    a.add_argument("--provenance", default=str(provenance.PROVENANCE_DIR))
    a.add_argument("--write", metavar="FILE", help="write the records as a manifest (Parquet) instead of printing")
    a.set_defaults(func=audit)
    c = sub.add_parser("config", help="check (or --write) the config files generated from the schema")
    c.add_argument("--write", action="store_true", help="rewrite them instead of checking")
    c.add_argument("--repo", default=str(config.SCHEMA_PATH.parents[2]), help="repository root")
    c.set_defaults(func=config_files)
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
