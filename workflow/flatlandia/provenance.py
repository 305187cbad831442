"""Audit trail: which rule, inputs, config, code version and commit produced each artifact.

Every rule script run through :func:`flatlandia.runlog.run` leaves a provenance record in
``logs/provenance/{rule}/{wildcards}.json``; the ``manifest`` rule gathers them into
``results/manifest.parquet`` and ``flatlandia audit`` prints them.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from flatlandia import __version__
from flatlandia.io import sha256, write_json

PROVENANCE_DIR = Path("logs/provenance")


def path_digest(path: str | Path) -> tuple[str, int]:
    """sha256 and size of a file; for a folder, of its sorted (name, file sha256) list."""
    p = Path(path)
    if p.is_dir():
        h, size = hashlib.sha256(), 0
        for f in sorted(q for q in p.rglob("*") if q.is_file() and q.name != ".snakemake_timestamp"):
            d = sha256(f)
            h.update(f"{f.relative_to(p)}\0{d}\n".encode())
            size += f.stat().st_size
        return h.hexdigest(), size
    if p.is_file():
        return sha256(p), p.stat().st_size
    return "", 0


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def git_commit() -> str:
    """The commit of the workflow's code, with '+dirty' when it has uncommitted changes."""
    repo = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (head or "unknown") + ("+dirty" if dirty else "")


def record(smk) -> dict:
    """The provenance record of a finished rule script (Snakemake's ``snakemake`` object)."""
    wildcards = dict(smk.wildcards.items()) if hasattr(smk.wildcards, "items") else {}
    return {
        "rule": smk.rule,
        "wildcards": wildcards,
        "finished_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "config_hash": config_hash(dict(smk.config)),
        "package_version": __version__,
        "git_commit": git_commit(),
        "inputs": {str(p): path_digest(p)[0] for p in smk.input},
        "outputs": {str(p): dict(zip(("sha256", "bytes"), path_digest(p))) for p in smk.output},
    }


def record_path(rule: str, wildcards: dict) -> Path:
    tag = "_".join(f"{k}-{v}" for k, v in sorted(wildcards.items())) or "all"
    return PROVENANCE_DIR / rule / f"{tag}.json"


def write_record(smk) -> Path:
    rec = record(smk)
    path = record_path(rec["rule"], rec["wildcards"])
    write_json(rec, path)
    return path


def manifest(folder: str | Path = PROVENANCE_DIR) -> pd.DataFrame:
    """One row per artifact, from every provenance record under ``folder``."""
    rows = []
    for f in sorted(Path(folder).rglob("*.json")):
        rec = json.loads(f.read_text())
        for path, out in rec["outputs"].items():
            rows.append(
                {
                    "artifact": path,
                    "rule": rec["rule"],
                    "scene": rec["wildcards"].get("scene", ""),
                    "wildcards": json.dumps(rec["wildcards"], sort_keys=True),
                    "sha256": out["sha256"],
                    "bytes": int(out["bytes"]),
                    "inputs": json.dumps(rec["inputs"], sort_keys=True),
                    "config_hash": rec["config_hash"],
                    "package_version": rec["package_version"],
                    "git_commit": rec["git_commit"],
                    "finished_at": rec["finished_at"],
                }
            )
    cols = [
        "artifact",
        "rule",
        "scene",
        "wildcards",
        "sha256",
        "bytes",
        "inputs",
        "config_hash",
        "package_version",
        "git_commit",
        "finished_at",
    ]
    return pd.DataFrame(rows, columns=cols).sort_values(["scene", "rule", "artifact"], ignore_index=True)
