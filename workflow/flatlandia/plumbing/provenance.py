"""Audit trail: which rule, inputs, settings, code version and commit produced each artifact.

Every rule script run through :func:`flatlandia.plumbing.rule_log.run` leaves a provenance record in
``logs/provenance/{rule}/{wildcards}.json``: the rule and its wildcards; its inputs with their
sha256 (their own producing rules are found from the other records); the settings the rule reads
(its resolved ``params``: the config keys it names, ``config_keys(...)`` in rules/common.smk, by
their dotted names, and the values it derives from the scene sheet) with their hash, so the same artifact
built by ``all`` or by ``maps --config select=[...]`` carries the same hash; the id of the whole
resolved config, stored once per id in ``logs/provenance/configs/{id}.json``; the commit of the
workflow folder that ran, whether it had uncommitted changes and which files; the scene sheet's
sha256; the software versions; start, end, wall and CPU time. The ``manifest`` rule gathers the
records into ``results/manifest.parquet``; ``flatlandia audit`` prints them, follows an artifact's
inputs back to the published files (``--tree``) and re-hashes every artifact (``--check``).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import resource
import subprocess
import sys
import time
from datetime import UTC, datetime
from functools import cache
from pathlib import Path

import pandas as pd

from flatlandia import __version__
from flatlandia.plumbing.files import sha256, write_json

PROVENANCE_DIR = Path("logs/provenance")
CONFIGS_DIR = PROVENANCE_DIR / "configs"

#: packages whose versions a record lists when the rule's process imported them
SOFTWARE = [
    "snakemake",
    "numpy",
    "pandas",
    "pyarrow",
    "scipy",
    "sklearn",
    "numba",
    "pyproj",
    "torch",
    "torch_geometric",
    "pycolmap",
    "open3d",
    "cv2",
    "kornia",
    "transformers",
    "matplotlib",
]

#: when the rule's script started (set by :func:`flatlandia.plumbing.rule_log.run`)
_STARTED: dict[str, float] = {}


def path_digest(path: str | Path) -> tuple[str, int]:
    """sha256 and size of a file; for a folder, of its sorted (name, file sha256) list (its regular
    files: a link inside it is not followed)."""
    p = Path(path)
    if p.is_dir():
        h, size = hashlib.sha256(), 0
        files = (q for q in p.rglob("*") if q.is_file() and not q.is_symlink() and q.name != ".snakemake_timestamp")
        for f in sorted(files):
            d = sha256(f)
            h.update(f"{f.relative_to(p)}\0{d}\n".encode())
            size += f.stat().st_size
        return h.hexdigest(), size
    if p.is_file():
        return sha256(p), p.stat().st_size
    return "", 0


def _plain(value):
    """A params value as JSON data (Snakemake's named lists, paths and numpy scalars included)."""
    if isinstance(value, dict) or hasattr(value, "items"):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    return str(value)


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def rule_settings(smk) -> dict:
    """The settings a rule reads: its resolved params by name (what reaches the script from the config;
    a config key by its dotted name, ``solver.top_k``), without the keys this job does not read (a
    ``config_keys(..., reads=...)`` param that is {} for it)."""
    params = smk.params
    names = list(params.keys()) if hasattr(params, "keys") else []
    return {name: _plain(params[name]) for name in names if not _unread(params[name])}


def _unread(value) -> bool:
    return (isinstance(value, dict) or hasattr(value, "items")) and not len(value)


def store_config(config: dict, folder: Path = CONFIGS_DIR) -> str:
    """Write the whole resolved config once under its id; returns the id."""
    cid = config_hash(config)
    path = folder / f"{cid}.json"
    if not path.exists():
        write_json(_plain(config), path)
    return cid


@cache
def workflow_state(folder: str) -> dict:
    """The git commit of the workflow folder that ran, whether it had uncommitted changes to
    tracked files, and which (cached per process)."""

    def git(*args) -> str:
        return subprocess.run(["git", "-C", folder, *args], capture_output=True, text=True, timeout=10).stdout

    try:
        head = git("rev-parse", "HEAD").strip()
        changed = [ln[3:] for ln in git("status", "--porcelain", "--untracked-files=no").splitlines() if ln.strip()]
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None, "modified": []}
    return {"commit": head or "unknown", "dirty": bool(changed), "modified": changed[:50]}


def software_versions() -> dict:
    """Python and the versions of the listed packages this process imported."""
    out = {"python": sys.version.split()[0], "flatlandia": __version__}
    for name in SOFTWARE:
        mod = sys.modules.get(name)
        if mod is not None:
            out[name] = str(getattr(mod, "__version__", "unknown"))
    return out


def started() -> None:
    """Mark the start of a rule's script (wall time of the record)."""
    _STARTED["t"] = time.time()


def _workflow_folder(smk) -> str:
    """The workflow folder that ran (``workflow/``, the parent of its scripts' folder), not the
    checkout the package was installed from; for a module from a remote source, the address of its
    scripts (with the tag, e.g. ``https://raw.githubusercontent.com/OWNER/REPO/v0.1.0/workflow/scripts``)."""
    scriptdir = getattr(smk, "scriptdir", None)
    if scriptdir and _remote(str(scriptdir)):
        return str(scriptdir)
    return str(Path(scriptdir).resolve().parent if scriptdir else Path(__file__).resolve().parents[2])


def _remote(folder: str) -> bool:
    return "://" in folder


def _workflow_record(folder: str) -> dict:
    """The commit of a workflow folder; for a remote source its address, which names the tag (the
    commit is not known here)."""
    if _remote(folder):
        return {"source": folder, "commit": folder, "dirty": None, "modified": []}
    return workflow_state(folder)


def _scene_sheet(config: dict, workflow_folder: str) -> Path:
    """The scene sheet the run read: as the workflow resolves it (the working folder, else the
    repository of a workflow run from a folder)."""
    p = Path(str(config.get("scenes", ""))).expanduser()
    if p.is_absolute() or p.exists() or _remote(workflow_folder):
        return p
    return Path(workflow_folder).parent / p


def record(smk) -> dict:
    """The provenance record of a finished rule script (Snakemake's ``snakemake`` object)."""
    wildcards = dict(smk.wildcards.items()) if hasattr(smk.wildcards, "items") else {}
    settings = rule_settings(smk)
    config = dict(smk.config)
    folder = _workflow_folder(smk)
    state = _workflow_record(folder)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    now = time.time()
    sheet = _scene_sheet(config, folder)
    rec = {
        "rule": smk.rule,
        "wildcards": wildcards,
        "started_at": datetime.fromtimestamp(_STARTED.get("t", now), UTC).isoformat(timespec="seconds"),
        "finished_at": datetime.fromtimestamp(now, UTC).isoformat(timespec="seconds"),
        "wall_seconds": round(now - _STARTED.get("t", now), 3),
        "cpu_seconds": round(usage.ru_utime + usage.ru_stime, 3),
        "settings": settings,
        "config_hash": config_hash(settings),
        "config_id": store_config(config) if config else "",
        "package_version": __version__,
        "git_commit": state["commit"] + ("+dirty" if state["dirty"] else ""),
        "workflow": state,
        "scene_sheet": {"path": str(sheet), "sha256": sha256(sheet) if sheet.is_file() else ""},
        "software": software_versions(),
        "inputs": {str(p): path_digest(p)[0] for p in smk.input},
        "outputs": {str(p): dict(zip(("sha256", "bytes"), path_digest(p))) for p in smk.output},
    }
    return rec


def record_path(rule: str, wildcards: dict) -> Path:
    tag = "_".join(f"{k}-{v}" for k, v in sorted(wildcards.items())) or "all"
    return PROVENANCE_DIR / rule / f"{tag}.json"


def write_record(smk) -> Path:
    rec = record(smk)
    path = record_path(rec["rule"], rec["wildcards"])
    write_json(rec, path)
    return path


def in_run(path: str | Path, root: str | Path | None = None) -> bool:
    """Whether an artifact a record names lies inside the run's folder ``root`` (default: the working
    folder): a relative path that stays there once links are resolved. The audit hashes nothing
    else, so a tampered record cannot make it read the filesystem root or a 40 GB file elsewhere."""
    p = Path(path)
    if p.is_absolute() or ".." in p.parts or not str(path).strip():
        return False
    base = Path(root or Path.cwd()).resolve()
    try:
        return (base / p).resolve().is_relative_to(base)
    except (OSError, RuntimeError):
        return False


#: keys a rule record must hold, and the type of each (what the manifest reads)
RECORD_KEYS = {
    "rule": str,
    "wildcards": dict,
    "inputs": dict,
    "outputs": dict,
    "config_hash": str,
    "package_version": str,
    "git_commit": str,
    "finished_at": str,
}


def record_problem(rec) -> str | None:
    """Why ``rec`` (a parsed record) is not a rule record this module wrote (None: it is one)."""
    if not isinstance(rec, dict):
        return f"not a JSON object but {type(rec).__name__}"
    for key, kind in RECORD_KEYS.items():
        if not isinstance(rec.get(key), kind):
            return f"'{key}' is missing or not {'text' if kind is str else 'an object'}"
    for path, out in rec["outputs"].items():
        if not isinstance(out, dict) or not isinstance(out.get("sha256"), str) or type(out.get("bytes")) is not int:
            return f"output {path!r}: expected {{sha256, bytes}}"
        if not in_run(path):
            return f"output {str(path)[:200]!r} lies outside the run's folder"
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in rec["inputs"].items()):
        return "'inputs' must map paths to sha256 digests"
    if not all(isinstance(v, (str, int, float)) for v in rec["wildcards"].values()):
        return "'wildcards' must map names to values"
    for key, kinds in (("workflow", dict), ("scene_sheet", dict), ("software", dict), ("settings", dict)):
        if key in rec and not isinstance(rec[key], kinds):
            return f"'{key}' must be an object"
    for key in ("wall_seconds", "cpu_seconds"):
        if key in rec and (isinstance(rec[key], bool) or not isinstance(rec[key], (int, float))):
            return f"'{key}' must be a number"
    if not re.fullmatch(r"[0-9a-f]{0,64}", str(rec.get("config_id", ""))):
        return "'config_id' must be a hex digest (it names a file of the stored configs)"
    return None


def records(folder: str | Path = PROVENANCE_DIR, skipped: list[str] | None = None) -> list[dict]:
    """Every rule record under ``folder`` (the stored configs excluded). A file that is not one
    (not a regular file, over :data:`flatlandia.plumbing.validate.MAX_RECORD_BYTES`, invalid JSON, a record
    lacking a key or naming an output outside the run) is left out, and said in ``skipped``."""
    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    folder = Path(folder)
    out = []
    files = []
    for dirpath, dirnames, filenames in os.walk(folder):  # links to other folders are not followed
        dirnames[:] = [d for d in dirnames if not (Path(dirpath) == folder and d == CONFIGS_DIR.name)]
        files += [Path(dirpath, n) for n in filenames if n.endswith(".json")]
    for f in sorted(files):
        try:
            rec = validate.read_json(f, validate.MAX_RECORD_BYTES, "MAX_RECORD_BYTES")
        except InputError as e:
            if skipped is not None:
                skipped.append(f"{e}: not a provenance record, left out")
            continue
        if isinstance(rec, dict) and "outputs" not in rec and "rule" not in rec:
            continue  # another JSON file kept beside the records
        why = record_problem(rec)
        if why:
            if skipped is not None:
                skipped.append(f"{f}: not a provenance record ({why}), left out")
            continue
        out.append(rec)
    return out


MANIFEST_COLUMNS = [
    "artifact",
    "rule",
    "scene",
    "wildcards",
    "sha256",
    "bytes",
    "inputs",
    "settings",
    "config_hash",
    "config_id",
    "package_version",
    "git_commit",
    "dirty",
    "scene_sheet",
    "software",
    "started_at",
    "finished_at",
    "wall_seconds",
    "cpu_seconds",
]


def manifest(folder: str | Path = PROVENANCE_DIR, skipped: list[str] | None = None) -> pd.DataFrame:
    """One row per artifact, from every provenance record under ``folder`` (those that are not
    records are left out and said in ``skipped``: :func:`records`)."""
    rows = []
    for rec in records(folder, skipped):
        state = rec.get("workflow", {})
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
                    "settings": json.dumps(rec.get("settings", {}), sort_keys=True, default=str),
                    "config_hash": rec["config_hash"],
                    "config_id": rec.get("config_id", ""),
                    "package_version": rec["package_version"],
                    "git_commit": rec["git_commit"],
                    "dirty": bool(state.get("dirty")) if state.get("dirty") is not None else None,
                    "scene_sheet": json.dumps(rec.get("scene_sheet", {}), sort_keys=True),
                    "software": json.dumps(rec.get("software", {}), sort_keys=True),
                    "started_at": rec.get("started_at", ""),
                    "finished_at": rec["finished_at"],
                    "wall_seconds": float(rec.get("wall_seconds", float("nan"))),
                    "cpu_seconds": float(rec.get("cpu_seconds", float("nan"))),
                }
            )
    return pd.DataFrame(rows, columns=MANIFEST_COLUMNS).sort_values(["scene", "rule", "artifact"], ignore_index=True)


# ----------------------------------------------------------------------------- audit


def producers(df: pd.DataFrame) -> dict[str, dict]:
    """artifact path -> its manifest row (as a dict)."""
    return {r["artifact"]: r for r in df.to_dict("records")}


def lineage(artifact: str, df: pd.DataFrame, tree: bool = False) -> list[dict]:
    """The inputs of ``artifact`` (one level, or with ``tree`` every level back to files no rule
    produced: the published data, the user's photos): per input its path, sha256 recorded by the
    consumer, the rule that produced it (empty for a source) and its depth."""
    rows = producers(df)
    out, seen = [], set()

    def walk(path: str, depth: int) -> None:
        rec = rows.get(path)
        if rec is None:
            return
        for inp, digest in sorted(json.loads(rec["inputs"]).items()):
            prod = rows.get(inp)
            out.append(
                {
                    "depth": depth,
                    "input": inp,
                    "sha256": digest,
                    "rule": prod["rule"] if prod else "",
                    "of": path,
                    "changed": bool(prod and digest and prod["sha256"] != digest),
                }
            )
            if tree and prod is not None and inp not in seen:
                seen.add(inp)
                walk(inp, depth + 1)

    walk(artifact, 1)
    return out


def _job(rec: dict) -> tuple[str, str]:
    """The job that wrote an artifact (its outputs share rule and wildcards)."""
    return rec["rule"], rec.get("wildcards") or "{}"


def _pattern(path: str, rec: dict | None) -> str:
    """A path with its scene's folder written as {scene}, to count one scene's files among many."""
    scene = str(rec.get("scene") or "") if rec else ""
    return path.replace(f"/{scene}/", "/{scene}/", 1) if scene else path


def _grouped(paths: list[str]) -> str:
    """Sibling paths as one: their common folder and the names in braces (a single path as is)."""
    if len(paths) == 1:
        return paths[0]
    folders = {str(Path(p).parent) for p in paths}
    if len(folders) == 1:
        return f"{folders.pop()}/{{{','.join(Path(p).name for p in paths)}}}"
    return ", ".join(paths)


def lineage_tree(artifact: str, df: pd.DataFrame) -> list[tuple[int, str]]:
    """The inputs of ``artifact`` back to the files no rule produced, as (depth, text) lines, each
    artifact's subtree once: the outputs of one job are one line; an input whose subtree is already
    listed is not listed again but counted on one line per kind (``results/{scene}/...``, how many,
    "listed above"); a job whose inputs are those of a job listed before says so. Why: shared
    subtrees (every run of the fine table reads the same 20 maps and queries) made the full tree of
    ``fine_localization.parquet`` 3,100 lines; this way it stays a few hundred."""
    rows = producers(df)
    shown: set[tuple] = set()  # jobs whose subtree is listed (or being listed)
    sources: set[str] = set()  # sources listed
    input_sets: dict[frozenset, str] = {}
    out: list[tuple[int, str]] = []

    def walk(path: str, depth: int) -> None:
        rec = rows.get(path)
        if rec is None:
            return
        inputs = dict(sorted(json.loads(rec["inputs"]).items()))
        key = frozenset(inputs)
        if len(key) > 1 and key in input_sets:
            out.append((depth, f"(its {len(key)} inputs are those of {input_sets[key]}, listed above)"))
            return
        input_sets.setdefault(key, path)
        groups: dict[tuple, list[str]] = {}
        for inp in inputs:
            prod = rows.get(inp)
            groups.setdefault(_job(prod) if prod else ("", inp), []).append(inp)
        again: dict[str, list[str]] = {}
        for job, paths in groups.items():
            prod = rows.get(paths[0])
            changed = [p for p in paths if prod and inputs[p] and rows[p]["sha256"] != inputs[p]]
            seen = job in shown if prod else paths[0] in sources
            if seen and not changed:
                again.setdefault(_pattern(_grouped(paths), prod), []).append(_grouped(paths))
                continue
            made = f"<- {prod['rule']}" if prod else "(source)"
            digest = f"  {inputs[paths[0]][:12]}" if len(paths) == 1 else ""
            flag = f"  CHANGED since used: {', '.join(changed)}" if changed else ""
            out.append((depth, f"{_grouped(paths)}{digest}  {made}{flag}"))
            if prod is None:
                sources.add(paths[0])
            elif not seen:
                shown.add(job)
                walk(paths[0], depth + 1)
        if again:
            listed = ", ".join(f"{len(ps)} x {p}" if len(ps) > 1 else ps[0] for p, ps in again.items())
            out.append((depth, f"listed above: {listed}"))

    start = rows.get(artifact)
    if start is not None:
        shown.add(_job(start))
    walk(artifact, 1)
    return out


def check(df: pd.DataFrame) -> pd.DataFrame:
    """Every recorded artifact re-hashed: rows whose file is missing or whose sha256 differs from
    its record (edited, replaced or truncated since the rule wrote it)."""
    bad = []
    for r in df.itertuples(index=False):
        digest, _ = path_digest(r.artifact)
        if digest != r.sha256:
            bad.append({"artifact": r.artifact, "rule": r.rule, "recorded": r.sha256, "now": digest or "(missing)"})
    return pd.DataFrame(bad, columns=["artifact", "rule", "recorded", "now"])


def stored_config(config_id: str, folder: str | Path = CONFIGS_DIR) -> dict | None:
    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    path = Path(folder) / f"{config_id}.json"
    if not (config_id and re.fullmatch(r"[0-9a-f]{1,64}", config_id) and path.exists()):
        return None
    try:
        value = validate.read_json(path, validate.MAX_RECORD_BYTES, "MAX_RECORD_BYTES")
    except InputError:
        return None
    return value if isinstance(value, dict) else None
