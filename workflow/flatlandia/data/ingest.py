"""Check what the published data holds for a scene before anything is built on it."""

from __future__ import annotations

import zipfile
from pathlib import Path

from flatlandia.data import published
from flatlandia.plumbing import files, ply
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.names import plain_name

#: files of a published scene: (key, path relative to the data root, required?)
SCENE_FILES = [
    ("reference_map", "individual_reference_maps/map_{scene}.json", True),
    ("transformations", "maps/{scene}/transformations.json", True),
    ("tokens", "maps/{scene}/tokens.txt", False),
    ("sfm_cameras", "maps/{scene}/SfM/cameras.bin", False),
    ("sfm_images", "maps/{scene}/SfM/images.zip", False),
    ("sfm_points3D", "maps/{scene}/SfM/points3D.bin", False),
    ("class_segmented_point_cloud", "maps/{scene}/class_segmented_point_cloud.ply", False),
    ("bbs", "maps/{scene}/bbs_for_segmented_objects.ply", False),
]
GLOBAL_FILES = ["scenes.tsv", "classes.tsv", "local_maps.json"]


def read_manifest(root: Path) -> dict[str, tuple[int, str]]:
    path = root / "MANIFEST.tsv"
    if not path.exists():
        return {}
    df = published.read_tsv(path, ["path", "bytes", "sha256"])
    return {r.path: (int(r.bytes), r.sha256) for r in df.itertuples(index=False)}


def _parse_check(key: str, path: Path) -> None:
    """Raise InputError if the file cannot be parsed as what it claims to be."""
    if key == "reference_map":
        published.read_reference_map(path)
    elif key == "transformations":
        published.read_transformations(path)
    elif key == "tokens":
        toks = [t for t in path.read_text().split() if t]
        if not toks:
            raise InputError(path, "no tokens")
        for t in toks:
            plain_name(t, path, "query token")
    elif key.endswith(".ply") or key in ("class_segmented_point_cloud", "bbs"):
        ply.check_header(path)
    elif key == "sfm_images":
        try:
            with zipfile.ZipFile(path) as z:
                bad = z.testzip()
                if bad is not None:
                    raise InputError(path, f"corrupt member {bad}")
                if not any(n.endswith("images.bin") for n in z.namelist()):
                    raise InputError(path, "zip holds no images.bin")
        except zipfile.BadZipFile as e:
            raise InputError(path, f"not a zip file ({e})") from e


def check_file(root: Path, rel: str, key: str, manifest: dict, verify_hash: bool) -> dict:
    path = root / rel
    rec = {
        "key": key,
        "path": rel,
        "present": path.exists(),
        "bytes": None,
        "manifest": rel in manifest,
        "size_ok": None,
        "sha256_ok": None,
        "parse_ok": None,
        "problem": "",
    }
    if not rec["present"]:
        rec["problem"] = "missing"
        return rec
    rec["bytes"] = path.stat().st_size
    if rel in manifest:
        size, digest = manifest[rel]
        rec["size_ok"] = rec["bytes"] == size
        if not rec["size_ok"]:
            rec["problem"] = f"size {rec['bytes']} != manifest {size} (truncated?)"
        elif verify_hash:
            rec["sha256_ok"] = files.sha256(path) == digest
            if not rec["sha256_ok"]:
                rec["problem"] = "sha256 differs from MANIFEST.tsv"
    try:
        _parse_check(key, path)
        rec["parse_ok"] = True
    except InputError as e:
        rec["parse_ok"] = False
        rec["problem"] = (rec["problem"] + "; " if rec["problem"] else "") + e.problem
    return rec


def optional_problems(report: dict) -> list[str]:
    """One line per optional file of a scene that is present but broken (truncated, corrupt): the
    run goes on, so the user hears of it on the console, not only in the rule's log (a missing
    optional file is the published data's normal state and says nothing)."""
    required = {k for k, _, req in SCENE_FILES if req} | {"local_maps"}
    return [
        f"{Path(report['root']) / f['path']}: {f['problem']}: an optional file of scene {report['scene']}, "
        "left as it is for the rules that read it: replace it with an intact copy (MANIFEST.tsv holds its size "
        "and sha256)"
        for f in report["files"]
        if f["key"] not in required and f["present"] and f["problem"]
    ]


def ingest_scene(root: str | Path, scene: str, verify_hash: bool = True) -> dict:
    """Report every file of a scene; raise InputError if a required one is missing or broken."""
    root = Path(root)
    manifest = read_manifest(root)
    records = [check_file(root, rel.format(scene=scene), key, manifest, verify_hash) for key, rel, _ in SCENE_FILES]
    local = check_file(root, "local_maps.json", "local_maps", manifest, verify_hash)
    records.append(local)
    required = {k for k, _, req in SCENE_FILES if req} | {"local_maps"}
    for rec in records:
        if rec["key"] in required and (not rec["present"] or rec["problem"]):
            raise InputError(root / rec["path"], f"required file for scene {scene}: {rec['problem']}")
    n_queries = len(published.read_local_maps(root / "local_maps.json", scene))
    return {
        "scene": scene,
        # the folder resolved: the record does not depend on where the run folder sits (the rule is
        # given it relative to the run folder where the user wrote a relative path)
        "root": str(root.resolve()),
        "files": records,
        "n_queries": n_queries,
        "available": {r["key"]: bool(r["present"] and not r["problem"]) for r in records},
    }
