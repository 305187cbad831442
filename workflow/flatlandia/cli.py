"""Command line: ``flatlandia audit`` prints the audit trail of a run (one scene or all)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from flatlandia import provenance


def audit(args) -> int:
    path = Path(args.manifest)
    df = pd.read_parquet(path) if path.exists() else provenance.manifest(args.provenance)
    if df.empty:
        print(f"no audit records: run the workflow first ({path} and {args.provenance} are empty)")
        return 1
    if args.scene:
        df = df[df["scene"] == args.scene]
    cols = ["artifact", "rule", "sha256", "bytes", "config_hash", "git_commit", "finished_at"]
    with pd.option_context("display.max_rows", None, "display.max_colwidth", 64, "display.width", 250):
        out = df[cols].assign(sha256=df["sha256"].str[:12])
        print(out.to_string(index=False))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="flatlandia", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("audit", help="print which rule, inputs, config and commit produced each artifact")
    a.add_argument("--scene", help="only this scene's artifacts")
    a.add_argument("--manifest", default="results/manifest.parquet")
    a.add_argument("--provenance", default=str(provenance.PROVENANCE_DIR))
    a.set_defaults(func=audit)
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
