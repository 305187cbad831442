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
import math
import os
import re
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
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
    try:
        base = os.path.realpath(root or os.getcwd())
        return Path(os.path.realpath(os.path.join(base, p))).is_relative_to(base)
    except (OSError, RuntimeError, ValueError):  # ValueError: a NUL in the name
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
    if not isinstance(rec.get("started_at", ""), str):
        return "'started_at' must be text"
    if not _hex_id(rec.get("config_id", "")):
        return "'config_id' must be a hex digest (it names a file of the stored configs)"
    return None


def _hex_id(value) -> bool:
    return isinstance(value, str) and re.fullmatch(r"[0-9a-f]{0,64}", value) is not None


def record_files(folder: str | Path = PROVENANCE_DIR) -> list[Path]:
    """The ``.json`` files under ``folder`` that may be records (the stored configs excluded), sorted;
    links to other folders are not followed."""
    folder = Path(folder)
    files = []
    for dirpath, dirnames, filenames in os.walk(folder):
        dirnames[:] = [d for d in dirnames if not (Path(dirpath) == folder and d == CONFIGS_DIR.name)]
        files += [Path(dirpath, n) for n in filenames if n.endswith(".json")]
    return sorted(files)


def records(folder: str | Path = PROVENANCE_DIR, skipped: list[str] | None = None) -> list[dict]:
    """Every rule record under ``folder`` (the stored configs excluded). A file that is not one
    (not a regular file, over :data:data:`flatlandia.plumbing.validate.MAX_RECORD_BYTES`, invalid JSON, a record
    lacking a key or naming an output outside the run) is left out, and said in ``skipped``."""
    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    out = []
    for f in record_files(folder):
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
                    "scene": str(rec["wildcards"].get("scene", "")),  # one type: the rows are sorted by it
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


#: rows of a manifest each said on a WARNING line when left out (the others counted on one line)
SKIPPED_SHOWN = 20
#: the manifest's columns the audit needs (:data:`MANIFEST_REQUIRED`) and the others' values where a
#: manifest written by an older version lacks them
MANIFEST_REQUIRED = ("artifact", "rule", "sha256", "inputs")
_MANIFEST_DEFAULTS = {
    "scene": "",
    "wildcards": "{}",
    "bytes": 0,
    "settings": "{}",
    "config_hash": "",
    "config_id": "",
    "package_version": "",
    "git_commit": "",
    "dirty": None,
    "scene_sheet": "{}",
    "software": "{}",
    "started_at": "",
    "finished_at": "",
    "wall_seconds": math.nan,
    "cpu_seconds": math.nan,
}
_MANIFEST_TEXT = ("artifact", "rule", "sha256", "config_hash", "package_version", "git_commit")
_MANIFEST_TEXT += ("started_at", "finished_at")
_MANIFEST_JSON = ("wildcards", "inputs", "settings", "scene_sheet", "software")


def read_manifest(path: str | Path, skipped: list[str]) -> pd.DataFrame:
    """The rows of a manifest Parquet (``results/manifest.parquet``) as :func:`manifest` makes them,
    each checked: a file that is not a manifest (not Parquet, over the bounds, no ``artifact`` column)
    is one InputError; a row whose cells are not what :func:`manifest` writes (bad JSON, a number
    where text is needed) is left out and said in ``skipped`` (:data:`SKIPPED_SHOWN` of them, the
    others counted). Why: the file is as easily edited as a record, and the audit reads its cells."""
    from flatlandia.plumbing.errors import InputError

    table, present = _manifest_table(path)
    missing = [c for c in MANIFEST_REQUIRED if c not in present]
    if missing:
        raise InputError(path, f"not a manifest of flatlandia: no {', '.join(repr(c) for c in missing)} column")
    rows, bad = [], 0
    for i, row in enumerate(table.to_pylist()):
        row = {c: row.get(c) if c in present else _MANIFEST_DEFAULTS[c] for c in MANIFEST_COLUMNS}
        why = manifest_row_problem(row)
        if why is None:
            rows.append(row)
            continue
        bad += 1
        if bad <= SKIPPED_SHOWN:
            skipped.append(f"{path}: row {i}: {why}, left out")
    if bad > SKIPPED_SHOWN:
        skipped.append(f"{path}: {bad - SKIPPED_SHOWN:,} more rows left out as not a manifest's")
    return pd.DataFrame(rows, columns=MANIFEST_COLUMNS)


def _manifest_table(path: str | Path):
    """(the manifest's pyarrow table, the names of :data:`MANIFEST_COLUMNS` it has), read through the
    Parquet door (:func:`flatlandia.plumbing.validate.read_parquet`: what it decodes to bounded by
    :data:`flatlandia.plumbing.validate.MAX_MANIFEST_BYTES`): only the manifest's own columns, so no other column is decoded; a
    column of nulls only (pyarrow's null type: ``dirty`` when no record knew) is not read, its cells
    are empty. A file that is not Parquet is InputError."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    bounds = (path, validate.MAX_MANIFEST_ROWS, validate.MAX_MANIFEST_BYTES, "rows", ("MAX_MANIFEST_ROWS", ""))
    try:
        validate.parquet_size(*bounds)  # the footer bounded before its schema is parsed
        schema = pq.read_schema(path)
        present = [c for c in MANIFEST_COLUMNS if c in schema.names]
        read = [c for c in present if not pa.types.is_null(schema.field(c).type)]
        return validate.read_parquet(*bounds, columns=read), present
    except InputError:
        raise
    except (pa.ArrowException, OSError, ValueError, KeyError) as e:  # KeyError: a column named twice
        raise InputError(path, f"not a Parquet manifest ({type(e).__name__}: {str(e)[:200]})") from None


def manifest_row_problem(row: dict) -> str | None:
    """Why a manifest row (every column of :data:`MANIFEST_COLUMNS`) is not one :func:`manifest`
    writes (None: it is one); ``scene`` is made text and ``bytes`` an int (a column of floats)."""
    for key in _MANIFEST_TEXT:
        if not isinstance(row[key], str):
            return f"{key!r} must be text, not {type(row[key]).__name__}"
    if not row["artifact"].strip():
        return "'artifact' is empty"
    if not isinstance(row["scene"], (str, int)) or isinstance(row["scene"], bool):
        return "'scene' must be text"
    row["scene"] = str(row["scene"])
    if not _hex_id(row["config_id"]):
        return "'config_id' must be a hex digest (it names a file of the stored configs)"
    size = row["bytes"]
    whole = isinstance(size, int) or (isinstance(size, float) and size.is_integer())
    if isinstance(size, bool) or not whole or not 0 <= size < 2**63:
        return "'bytes' must be a count of bytes"
    row["bytes"] = int(size)
    for key in ("wall_seconds", "cpu_seconds"):
        row[key] = math.nan if row[key] is None else row[key]  # an empty cell: not measured
        if isinstance(row[key], bool) or not isinstance(row[key], (int, float)):
            return f"{key!r} must be a number"
    if not isinstance(row["dirty"], (bool, type(None))):
        return "'dirty' must be true, false or empty"
    return _json_cells_problem(row)


def _json_cells_problem(row: dict) -> str | None:
    """Why a manifest row's JSON cells (:data:`_MANIFEST_JSON`) are not objects as :func:`manifest`
    writes them (None: they are), read through :func:`flatlandia.plumbing.validate.parse_json`; each is
    written again as :func:`manifest` writes it, so the audit's own ``json.loads`` of it cannot fail
    (a 5,000-digit number is a float by then)."""
    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    values = {}
    for key in _MANIFEST_JSON:
        try:
            values[key] = validate.parse_json(row[key], key) if isinstance(row[key], str) else None
        except InputError as e:
            return f"{key!r}: {e.problem}"
        if not isinstance(values[key], dict):
            return f"{key!r} must be a JSON object as text"
    if not all(isinstance(v, str) for v in values["inputs"].values()):
        return "'inputs' must map paths to sha256 digests"
    row.update({key: json.dumps(v, sort_keys=True) for key, v in values.items()})
    return None


# ----------------------------------------------------------------------------- audit


def producers(df: pd.DataFrame) -> dict[str, dict]:
    """artifact path -> its manifest row (as a dict)."""
    return {r["artifact"]: r for r in df.to_dict("records")}


def lineage(artifact: str, df: pd.DataFrame, tree: bool = False) -> list[dict]:
    """The inputs of ``artifact`` (one level, or with ``tree`` every level back to files no rule
    produced: the published data, the user's photos; at most :data:`flatlandia.plumbing.validate.MAX_TREE_DEPTH` levels): per
    input its path, sha256 recorded by the consumer, the rule that produced it (empty for a source)
    and its depth. Walked with a stack of its own, not recursion: a chain of 1,500 records is no
    RecursionError."""
    from flatlandia.plumbing import validate

    rows = producers(df)
    out, seen = [], set()

    def walk(path: str, depth: int) -> Iterator[tuple[str, int]]:
        for inp, digest in sorted(json.loads(rows[path]["inputs"]).items()):
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
            if tree and prod is not None and inp not in seen and depth < validate.MAX_TREE_DEPTH:
                seen.add(inp)
                yield inp, depth + 1

    if artifact in rows:
        _depth_first(walk(artifact, 1), walk)
    return out


def _depth_first(first: Iterator[tuple[str, int]], walk) -> None:
    """Run a depth-first walk without recursion: ``walk(path, depth)`` is a generator that does one
    node's work and yields each child to visit (``(path, depth)``) where the recursive walk would
    have called itself; the child is walked whole before its parent goes on, as in the recursion."""
    stack = [first]
    while stack:
        child = next(stack[-1], None)
        if child is None:
            stack.pop()
        else:
            stack.append(walk(*child))


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
    ``fine_localization.parquet`` 3,100 lines; this way it stays a few hundred. At most
    :data:`flatlandia.plumbing.validate.MAX_TREE_DEPTH` levels, walked without recursion (:func:`_depth_first`)."""
    from flatlandia.plumbing import validate

    rows = producers(df)
    shown: set[tuple] = set()  # jobs whose subtree is listed (or being listed)
    sources: set[str] = set()  # sources listed
    input_sets: dict[frozenset, str] = {}
    out: list[tuple[int, str]] = []

    def walk(path: str, depth: int) -> Iterator[tuple[str, int]]:
        rec = rows.get(path)
        if rec is None:
            return
        inputs = dict(sorted(json.loads(rec["inputs"]).items()))
        key = frozenset(inputs)
        if len(key) > 1 and key in input_sets:
            out.append((depth, f"(its {len(key)} inputs are those of {input_sets[key]}, listed above)"))
            return
        if depth > validate.MAX_TREE_DEPTH:
            out.append(
                (
                    depth,
                    f"(its inputs left out: the tree stops at {validate.MAX_TREE_DEPTH} levels, validate.MAX_TREE_DEPTH)",
                )
            )
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
                yield paths[0], depth + 1
        if again:
            listed = ", ".join(f"{len(ps)} x {p}" if len(ps) > 1 else ps[0] for p, ps in again.items())
            out.append((depth, f"listed above: {listed}"))

    start = rows.get(artifact)
    if start is not None:
        shown.add(_job(start))
    _depth_first(walk(artifact, 1), walk)
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
