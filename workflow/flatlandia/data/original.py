"""The benchmark in the authors' own form (rule ``export_original``, target ``export``): the files
``data/flatlandia.json``, ``data/region_proposal.json`` and ``data/local_maps.json`` laid out as the
authors' repository (IIT-PAVIS/Flatlandia) expects them, and a reader that checks them as their
fine-localization code uses them.

Why: the authors published their code and ``local_maps.json`` but not ``flatlandia.json`` (maps,
query poses, split) nor ``region_proposal.json``, so their baselines cannot run on the published
data. The workflow recovers all that their fine-localization path reads; this module writes it in
their schema. What is not recoverable (image boxes, cameras) is written as null; the split is the
workflow's, not the original one (unpublished).

Their frame, per map: lon/lat degrees minus a centre, times ``2 / to_flatlandia`` (one unit is
``tf / 2`` degrees in lon and in lat alike: not metric). The original centre is not published; the
bounding-box centre of the map's objects (:func:`map_centre`) keeps every map in (-1, 1) and
reproduces every published GT local map to about 1e-11 units (measured on the 20 scenes). A query's
``theta`` is the camera's viewing axis counter-clockwise from +x of that frame, in degrees (rule
recover's ``theta_lonlat_deg``, not the metric ``theta_deg``); a GT local map is that camera's view
of its objects, :func:`local_map`.

Entry functions: :func:`original_export` (the three files and the README as values) and
:func:`write` (staged, read back and checked before anything is moved into place); :func:`read`
is the reader, :func:`scene_pose` turns a pose of their frame back into the scene's metric frame.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, proposals, vocabulary
from flatlandia.classes import CLASSES
from flatlandia.data import export
from flatlandia.plumbing import escape, files
from flatlandia.plumbing.errors import InputError

#: the export's files, by name, relative to its folder (results/export/original/)
FILES = {
    "flatlandia": "data/flatlandia.json",
    "region_proposal": "data/region_proposal.json",
    "local_maps": "data/local_maps.json",
    "readme": "README.md",
}
TO_FLATLANDIA = geo.TO_FLATLANDIA
N_CLASSES = len(CLASSES)
#: the workflow's map types -> their keys (region_proposal.json's first level, local_maps.json's last)
MAP_TYPE_KEYS = {"gt": "GT", "depth": "depth"}
#: the workflow's splits -> their keys
SPLIT_KEYS = {"train": "training", "val": "validation", "test": "testing"}
#: their "simple" queries: more than 4 objects (their loader's subset option); "hard": the others
SIMPLE_MIN_OBJECTS = 5
SUBSETS = ("simple", "hard")
#: region_proposal.json's second level: every query, or the simple ones
PROPOSAL_SUBSETS = {"all": SUBSETS, "easy": ("simple",)}
#: the oracle box under their key
ORACLE_KEY = "CoarseBB"
#: a coarse loss -> their key's prefix; a strategy -> its suffix (N_LM, 2N_LM, R_30)
LOSS_KEYS = {"sim": "simil", "trip": "triplet", "simtrip": "mix"}  # vocabulary.COARSE_LOSSES
STRATEGY_KEYS = {"N_LM": "nq", "2N_LM": "2nq", "R_30": "circle"}
#: the coarse proposals their schema has a key for (the solver's has none)
SOURCES = [s for s in vocabulary.COARSE_PROPOSALS if vocabulary.coarse_source(s) in LOSS_KEYS]
#: keys their script offers that the paper does not define: not written
UNDEFINED_KEYS = ("NoisyGT",)
#: how far an exported GT local map may be from the published one, in their units (measured: 1.2e-11)
LOCAL_MAP_TOL = 1e-9


def proposal_key(source: str, strategy: str) -> str:
    """Their key of a coarse proposal: ``coarse-simtrip`` with ``2N_LM`` is ``mix_2nq``."""
    return f"{LOSS_KEYS[vocabulary.coarse_source(source)]}_{STRATEGY_KEYS[strategy]}"


# ----------------------------------------------------------------------------- their frame
def map_centre(lonlat) -> np.ndarray:
    """The normalisation centre of a map: the bounding-box centre of its objects (lon, lat)."""
    lonlat = np.asarray(lonlat, float).reshape(-1, 2)
    return (lonlat.min(axis=0) + lonlat.max(axis=0)) / 2.0


def to_units(lonlat, centre) -> np.ndarray:
    """lon/lat degrees -> their map units around ``centre``."""
    return (np.asarray(lonlat, float).reshape(-1, 2) - np.asarray(centre, float)) * (2.0 / TO_FLATLANDIA)


def to_lonlat(xy, centre) -> np.ndarray:
    """Their map units around ``centre`` -> lon/lat degrees."""
    return np.asarray(xy, float).reshape(-1, 2) * (TO_FLATLANDIA / 2.0) + np.asarray(centre, float)


def local_map(objects_xy, camera_xy, theta_deg: float) -> np.ndarray:
    """The objects seen from a camera of their frame (camera at the origin looking along +x, +y to
    its left): how the published GT local maps are made."""
    return geo.world_to_local(np.asarray(objects_xy, float).reshape(-1, 2), camera_xy, math.radians(theta_deg))


def scene_pose(xy, theta_deg, centre, frame: geo.MetricFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses of their frame (``xy`` (N, 2) units around ``centre``, ``theta_deg`` (N,)) in the
    scene's metric frame: (x_m, y_m, theta_deg), what ``flatlandia score`` reads."""
    xy_m = frame.to_xy(to_lonlat(xy, centre))
    theta = np.degrees(frame.heading_to_metric(np.radians(np.asarray(theta_deg, float).reshape(-1))))
    return xy_m[:, 0], xy_m[:, 1], theta


# ----------------------------------------------------------------------------- writing
def _object_keys(ref: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    ref = ref.sort_values("obj_idx", kind="stable").reset_index(drop=True)
    if ref["obj_idx"].duplicated().any():
        raise InputError(f"scene {ref['scene'].iloc[0]} reference map", "obj_idx repeats")
    return ref, [str(int(o)) for o in ref["obj_idx"]]


def _scene_queries(scene: str, recovered: pd.DataFrame, queries: pd.DataFrame) -> pd.DataFrame:
    """The queries (their order, split, matches) with rule recover's pose in lon/lat degrees."""
    rec = recovered.set_index(recovered["token"].astype(str))
    tokens = queries["token"].astype(str)
    missing = sorted(set(tokens) - set(rec.index))
    if missing:
        raise InputError(f"scene {scene} recovered queries", f"no recovered pose for {missing[:5]}")
    out = queries.assign(token=tokens).reset_index(drop=True)
    for c in ("lon", "lat", "theta_lonlat_deg"):
        out[f"rec_{c}"] = rec.loc[tokens, c].to_numpy(float)
    return out


def scene_map(scene: str, ref: pd.DataFrame, recovered: pd.DataFrame, queries: pd.DataFrame) -> tuple[dict, np.ndarray]:
    """``maps[scene]`` of flatlandia.json and the map's centre: objects by key (``str(obj_idx)``, in
    ``obj_idx`` order: a proposal's index into ``object_list`` is the object's ``obj_idx`` position),
    queries with their camera, theta and matched objects; detections and intrinsics null."""
    ref, keys = _object_keys(ref)
    lonlat = ref[["lon", "lat"]].to_numpy(float)
    centre = map_centre(lonlat)
    xy = to_units(lonlat, centre)
    objects = {
        k: {"xy": [float(v) for v in p], "class": int(c)}
        for k, p, c in zip(keys, xy, ref["class_id"].to_numpy(), strict=True)
    }
    key_of = {int(o): k for o, k in zip(ref["obj_idx"], keys, strict=True)}
    q = _scene_queries(scene, recovered, queries)
    cams = to_units(q[["rec_lon", "rec_lat"]].to_numpy(float), centre)
    out_q = {}
    for r, cam in zip(q.itertuples(index=False), cams, strict=True):
        try:
            seen = [key_of[int(i)] for i in r.ref_idx]
        except KeyError as e:
            raise InputError(f"scene {scene} queries", f"query {r.token} matches object {e} not in the map") from None
        out_q[r.token] = {
            "xy": [float(v) for v in cam],
            "theta": float(r.rec_theta_lonlat_deg),
            "detected_objects": seen,
            "detections": dict.fromkeys(seen),  # image boxes: not recoverable (their loader indexes it by key)
            "intrinsics": None,  # the camera: not recoverable
        }
    return {"object_list": keys, "objects": objects, "queries": out_q}, centre


def subset(n_objects: int) -> str:
    """Their subset of a query: ``simple`` (more than 4 objects) or ``hard``."""
    return "simple" if n_objects >= SIMPLE_MIN_OBJECTS else "hard"


def split_json(scenes: list[dict]) -> dict:
    """``miscellanea.split``: token -> scene, and per subset and split the tokens (scenes', then
    queries' order)."""
    out = {"img_to_scene": {}, **{s: {k: [] for k in SPLIT_KEYS.values()} for s in SUBSETS}}
    for s in scenes:
        for r in s["queries"].itertuples(index=False):
            token = str(r.token)
            if token in out["img_to_scene"]:
                raise InputError(
                    f"scene {s['scene']} queries",
                    f"token {token} is a query of scene "
                    f"{out['img_to_scene'][token]} too: their split maps a token to one scene",
                )
            if r.split not in SPLIT_KEYS:
                raise InputError(f"scene {s['scene']} queries", f"query {token}: unknown split {r.split!r}")
            out["img_to_scene"][token] = str(s["scene"])
            out[subset(int(r.n_objects))][SPLIT_KEYS[r.split]].append(token)
    return out


def _workflow_notes(scenes: list[dict], centres: dict[str, np.ndarray]) -> dict:
    """``miscellanea.flatlandia_workflow``: what this file is and how its numbers were made (their
    loader reads ``miscellanea.split`` only)."""
    qmeta = scenes[0]["queries_meta"] if scenes else {}
    return {
        "written_by": "the Flatlandia workflow (rule export_original): regenerated, not the authors' file",
        "to_flatlandia": TO_FLATLANDIA,
        "xy": "(lon, lat) minus the map's centre, times 2 / to_flatlandia (the same scale for lon and lat)",
        "centre": "the bounding-box centre of the map's objects (the original centre is not published)",
        "theta": "degrees, the camera's viewing axis counter-clockwise from +x of the xy frame",
        "maps": {
            sid: {"centre_lonlat": [float(v) for v in centres[sid]], **{k: frame[k] for k in ("crs", "lon0", "lat0")}}
            for sid, frame in ((str(s["scene"]), export.frame_json(str(s["scene"]), s["meta"])) for s in scenes)
        },
        "split": {
            "original": False,
            "seed": qmeta.get("seed"),
            "fractions": qmeta.get("split"),
            "note": "the workflow's seeded split per scene (config seed and split), not the original one (not published)",
        },
        "subsets": "simple: queries with more than 4 objects; hard: the others",
        "null": "detections (image boxes, by object key) and intrinsics (the camera): not recoverable from the published data",
    }


def flatlandia_json(scenes: list[dict]) -> dict:
    """flatlandia.json. ``scenes``: per benchmark scene (in order) a dict with ``scene``, ``ref`` and
    ``meta`` (reference_map.parquet and its metadata), ``recovered`` (rule recover's table),
    ``queries`` and ``queries_meta`` (queries.parquet and its metadata)."""
    maps, centres = {}, {}
    for s in scenes:
        sid = str(s["scene"])
        maps[sid], centres[sid] = scene_map(sid, s["ref"], s["recovered"], s["queries"])
    return {
        "maps": maps,
        "miscellanea": {"split": split_json(scenes), "flatlandia_workflow": _workflow_notes(scenes, centres)},
    }


def region_proposal_json(scenes: list[dict], coarse: Mapping[str, pd.DataFrame]) -> dict:
    """region_proposal.json: per map type (GT, depth) and subset (all, easy), ``CoarseBB`` (the oracle
    GT-BB box, every query) and the coarse proposals given (``coarse``: source -> the proposal table
    of rule coarse_eval, every scene; the test split) under their keys; each value is a list whose
    first element is the region's indices into ``object_list``."""
    unknown = sorted(set(coarse) - set(SOURCES))
    if unknown:
        raise ValueError(f"proposal sources without a key in their schema {unknown}; known: {SOURCES}")
    entries: dict[str, dict[str, dict[str, list]]] = {m: {} for m in MAP_TYPE_KEYS.values()}
    simple: set[str] = set()
    for s in scenes:
        scene = str(s["scene"])
        ref, _ = _object_keys(s["ref"])
        pos = {int(o): i for i, o in enumerate(ref["obj_idx"])}
        q = s["queries"]
        tokens = set(q["token"].astype(str))
        simple |= {str(t) for t, n in zip(q["token"], q["n_objects"], strict=True) if subset(int(n)) == "simple"}
        box = proposals.gtbb_proposals(ref, q)
        for m in MAP_TYPE_KEYS.values():
            entries[m].setdefault(ORACLE_KEY, {}).update(
                {str(r.token): [_indices(r.proposal, pos, scene, r.token)] for r in box.itertuples(index=False)}
            )
        for source in SOURCES:
            if source not in coarse:
                continue
            t = coarse[source]
            t = t[(t["scene"].astype(str) == scene) & t["token"].astype(str).isin(tokens)]
            strange = sorted(set(t["strategy"]) - set(STRATEGY_KEYS)) + sorted(set(t["map_type"]) - set(MAP_TYPE_KEYS))
            if strange:
                raise InputError(
                    f"{source} proposals", f"strategies or map types without a key in their schema {strange}"
                )
            for r in t.itertuples(index=False):
                key = proposal_key(source, str(r.strategy))
                entries[MAP_TYPE_KEYS[r.map_type]].setdefault(key, {})[str(r.token)] = [
                    _indices(r.proposal, pos, scene, r.token)
                ]
    order = [ORACLE_KEY] + [proposal_key(s, k) for s in SOURCES for k in STRATEGY_KEYS]
    out = {}
    for m, by_key in entries.items():
        keys = [k for k in order if k in by_key]
        out[m] = {
            "all": {k: by_key[k] for k in keys},
            "easy": {k: {t: v for t, v in by_key[k].items() if t in simple} for k in keys},
        }
    return out


def _indices(proposal, pos: dict[int, int], scene: str, token) -> list[int]:
    try:
        return [pos[int(o)] for o in proposal]
    except KeyError as e:
        raise InputError(f"scene {scene} proposals", f"query {token}: object {e} is not in the map") from None


def local_maps_json(published: Mapping, data: dict, source: str | Path = "local_maps.json") -> dict:
    """local_maps.json: the published local maps (``published``, the parsed file at ``source``) of
    the exported queries, scenes and tokens in flatlandia.json's order (the GT maps are what the
    exported poses reproduce; the depth maps cannot be regenerated)."""
    out: dict[str, dict] = {}
    for sid, m in data["maps"].items():
        have = published.get(sid)
        if not isinstance(have, Mapping):
            raise InputError(source, f"no local maps of scene {sid}")
        out[sid] = {}
        for token in m["queries"]:
            if not isinstance(have.get(token), Mapping):
                raise InputError(source, f"scene {sid}: no local maps of query {token}")
            out[sid][token] = {k: have[token][k] for k in MAP_TYPE_KEYS.values()}
    return out


def original_export(
    scenes: list[dict],
    coarse: Mapping[str, pd.DataFrame],
    published_local_maps: Mapping,
    source: str | Path = "local_maps.json",
) -> dict:
    """Rule export_original: the values of :data:`FILES` by name (three dicts for JSON, the README's
    text). ``scenes``: as :func:`flatlandia_json`; ``coarse``: the coarse proposal tables present, by
    source (those of :data:`SOURCES`); ``published_local_maps``: the published local_maps.json
    (parsed; ``source``: its path, for the errors)."""
    data = flatlandia_json(scenes)
    rp = region_proposal_json(scenes, {s: t for s, t in coarse.items() if s in SOURCES})
    lm = local_maps_json(published_local_maps, data, source)
    return {
        "flatlandia": data,
        "region_proposal": rp,
        "local_maps": lm,
        "readme": readme_text(data, rp, [s for s in SOURCES if s not in coarse]),
    }


def json_text(value) -> str:
    """JSON as written: compact, no NaN, floats that read back to the same double."""
    return json.dumps(value, allow_nan=False) + "\n"


def write(folder: str | Path, out: dict, *, reads=()) -> None:
    """Write :func:`original_export`'s ``out`` under ``folder`` as :data:`FILES`, together: the files
    are staged, read back through :func:`read` (checked as their code uses them, the GT local maps
    against the poses) and moved into place only then, so a file that would not load is never written."""
    with files.staged(folder, FILES.values(), reads=reads) as tmp:
        for name, rel in FILES.items():
            text = out[name] if name == "readme" else json_text(out[name])
            tmp[rel].write_text(text)
        read({n: tmp[rel] for n, rel in FILES.items()}, tol=LOCAL_MAP_TOL)


# ----------------------------------------------------------------------------- reading
def _finite_xy(value, path, key: str, inside: bool = True) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 2 or not all(_number(v) for v in value):
        raise InputError(path, f"{key}: expected [x, y] numbers, got {str(value)[:80]}")
    xy = np.asarray(value, float)
    if not np.isfinite(xy).all():
        raise InputError(path, f"{key}: not finite ({value})")
    if inside and (np.abs(xy) >= 1.0).any():
        raise InputError(path, f"{key}: {value} outside (-1, 1), the range their maps are normalised to")
    return xy


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _need(d, key, kind, path, where: str):
    if not isinstance(d, Mapping) or key not in d:
        raise InputError(path, f"{where}: missing key {key!r}")
    if not isinstance(d[key], kind):
        raise InputError(path, f"{where}[{key!r}]: expected {getattr(kind, '__name__', kind)}")
    return d[key]


def check_flatlandia(data, path) -> None:
    """flatlandia.json as their loader reads it: every map's objects (``xy`` in (-1, 1), ``class``
    0..41) and queries (``xy`` in (-1, 1), finite ``theta``, ``detected_objects`` in
    ``object_list``, ``detections`` by those keys, ``intrinsics``), and a split in which every query
    is listed once, simple ones having more than 4 objects. InputError names the file and the key."""
    maps = _need(data, "maps", dict, path, "top level")
    for sid, m in maps.items():
        where = f"maps[{sid!r}]"
        keys = _need(m, "object_list", list, path, where)
        objects = _need(m, "objects", dict, path, where)
        if len(set(keys)) != len(keys) or not all(isinstance(k, str) for k in keys):
            raise InputError(path, f"{where}.object_list: keys must be distinct strings")
        if set(keys) != set(objects):
            raise InputError(path, f"{where}: object_list and objects hold different keys")
        for k in keys:
            o = objects[k]
            _finite_xy(_need(o, "xy", list, path, f"{where}.objects[{k!r}]"), path, f"{where}.objects[{k!r}].xy")
            c = _need(o, "class", int, path, f"{where}.objects[{k!r}]")
            if isinstance(c, bool) or not 0 <= c < N_CLASSES:
                raise InputError(path, f"{where}.objects[{k!r}].class: {c} outside 0..{N_CLASSES - 1}")
        known = set(keys)
        for token, q in _need(m, "queries", dict, path, where).items():
            w = f"{where}.queries[{token!r}]"
            _finite_xy(_need(q, "xy", list, path, w), path, f"{w}.xy")
            theta = q.get("theta") if isinstance(q, Mapping) else None
            if not _number(theta) or not math.isfinite(theta):
                raise InputError(path, f"{w}.theta: expected a finite number of degrees, got {theta!r}")
            seen = _need(q, "detected_objects", list, path, w)
            if len(seen) < geo.MIN_OBJECTS or not set(seen) <= known or len(set(seen)) != len(seen):
                raise InputError(
                    path, f"{w}.detected_objects: expected at least {geo.MIN_OBJECTS} distinct keys of object_list"
                )
            det = _need(q, "detections", dict, path, w)
            if not set(seen) <= set(det):
                raise InputError(path, f"{w}.detections: no entry for {sorted(set(seen) - set(det))[:3]}")
            if "intrinsics" not in q:
                raise InputError(path, f"{w}: missing key 'intrinsics'")
    split = _need(_need(data, "miscellanea", dict, path, "top level"), "split", dict, path, "miscellanea")
    to_scene = _need(split, "img_to_scene", dict, path, "miscellanea.split")
    listed: dict[str, str] = {}
    for sub in SUBSETS:
        lists = _need(split, sub, dict, path, "miscellanea.split")
        for k in SPLIT_KEYS.values():
            where = f"miscellanea.split.{sub}.{k}"
            for token in _need(lists, k, list, path, f"miscellanea.split.{sub}"):
                if token in listed:
                    raise InputError(path, f"{where}: token {token!r} is listed twice (also in {listed[token]})")
                listed[token] = where
                sid = to_scene.get(token)
                if sid is None or str(sid) not in maps or token not in maps[str(sid)]["queries"]:
                    raise InputError(
                        path, f"{where}: token {token!r} has no query in miscellanea.split.img_to_scene's map"
                    )
                n = len(maps[str(sid)]["queries"][token]["detected_objects"])
                if (sub == "simple") != (n >= SIMPLE_MIN_OBJECTS):
                    raise InputError(path, f"{where}: token {token!r} has {n} objects, not a {sub} query")
    queries = {t for m in maps.values() for t in m["queries"]}
    for what, tokens in (("miscellanea.split.img_to_scene", set(to_scene)), ("maps[*].queries", queries)):
        if tokens != set(listed):
            extra = sorted(tokens - set(listed))[:3]
            raise InputError(
                path, f"{what}: tokens that no split lists {extra}" if extra else f"{what}: tokens missing"
            )


def check_region_proposal(rp, data, path) -> None:
    """region_proposal.json as their code reads it (``rp[mode][subset][key][token][0]``): modes GT
    and depth, subsets all and easy (simple queries only), ``CoarseBB`` for every query of its subset
    (their script reads a proposal for every split), each region a list of distinct indices into the
    token's ``object_list``."""
    maps, to_scene = data["maps"], data["miscellanea"]["split"]["img_to_scene"]
    split = data["miscellanea"]["split"]
    for mode in MAP_TYPE_KEYS.values():
        for sub, subsets in PROPOSAL_SUBSETS.items():
            by_key = _need(_need(rp, mode, dict, path, "top level"), sub, dict, path, mode)
            tokens = {t for s in subsets for k in SPLIT_KEYS.values() for t in split[s][k]}
            box = _need(by_key, ORACLE_KEY, dict, path, f"{mode}.{sub}")
            if set(box) != tokens:
                raise InputError(path, f"{mode}.{sub}.{ORACLE_KEY}: not every query of the subset has its box")
            for key, regions in by_key.items():
                if not isinstance(regions, dict):
                    raise InputError(path, f"{mode}.{sub}.{key}: expected {{token: [indices]}}")
                for token, region in regions.items():
                    where = f"{mode}.{sub}.{key}[{token!r}]"
                    if token not in tokens:
                        raise InputError(path, f"{where}: not a query of subset {sub}")
                    n = len(maps[str(to_scene[token])]["object_list"])
                    idx = region[0] if isinstance(region, list) and region else None
                    if (
                        not isinstance(idx, list)
                        or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < n for i in idx)
                        or len(set(idx)) != len(idx)
                    ):
                        raise InputError(path, f"{where}[0]: expected distinct indices into object_list (0..{n - 1})")


def check_local_maps(lm, data, path, tol: float | None = None) -> None:
    """local_maps.json for every query of flatlandia.json: ``GT`` and ``depth`` with one finite [x, y]
    per detected object; with ``tol``, every GT map equals the camera's view of its objects
    (:func:`local_map`) to within ``tol`` units."""
    for sid, m in data["maps"].items():
        scene = _need(lm, sid, dict, path, "top level")
        xy = {k: np.asarray(o["xy"], float) for k, o in m["objects"].items()}
        for token, q in m["queries"].items():
            maps = _need(scene, token, dict, path, f"[{sid!r}]")
            n = len(q["detected_objects"])
            for mt in MAP_TYPE_KEYS.values():
                where = f"[{sid!r}][{token!r}][{mt!r}]"
                pts = _need(maps, mt, list, path, f"[{sid!r}][{token!r}]")
                for i, p in enumerate(pts):
                    _finite_xy(p, path, f"{where}[{i}]", inside=False)
                if len(pts) != n:
                    raise InputError(path, f"{where}: {len(pts)} objects, detected_objects {n}")
            if tol is not None:
                view = local_map([xy[k] for k in q["detected_objects"]], q["xy"], q["theta"])
                off = float(np.abs(view - np.asarray(maps["GT"], float)).max())
                if not off <= tol:
                    raise InputError(
                        path, f"[{sid!r}][{token!r}]['GT']: {off:.3g} units from the pose's view (tolerance {tol:g})"
                    )


def read(paths: Mapping[str, str | Path] | str | Path, tol: float | None = None) -> dict:
    """The three JSON files (``paths``: the export's folder, or name -> file as :data:`FILES`),
    parsed and checked (:func:`check_flatlandia`, :func:`check_region_proposal`,
    :func:`check_local_maps`, with ``tol`` on the GT maps); returns them by name."""
    if not isinstance(paths, Mapping):
        paths = {n: Path(paths) / rel for n, rel in FILES.items()}
    out = {n: files.read_json(paths[n]) for n in ("flatlandia", "region_proposal", "local_maps")}
    check_flatlandia(out["flatlandia"], paths["flatlandia"])
    check_region_proposal(out["region_proposal"], out["flatlandia"], paths["region_proposal"])
    check_local_maps(out["local_maps"], out["flatlandia"], paths["local_maps"], tol)
    return out


# ----------------------------------------------------------------------------- the README
def readme_text(data: dict, rp: dict, absent: list[str]) -> str:
    """results/export/original/README.md: what is regenerated, what is null, the centres, the split,
    the proposals present and absent."""
    md = escape.markdown
    notes = data["miscellanea"]["flatlandia_workflow"]
    split = data["miscellanea"]["split"]
    n_q = {sub: {k: len(v) for k, v in split[sub].items()} for sub in SUBSETS}
    keys = {m: list(v["all"]) for m, v in rp.items()}
    centres = "\n".join(
        f"| {md(sid)} | {m['centre_lonlat'][0]!r} | {m['centre_lonlat'][1]!r} | {len(data['maps'][sid]['object_list'])} "
        f"| {len(data['maps'][sid]['queries'])} |"
        for sid, m in notes["maps"].items()
    )
    fr = notes["split"]["fractions"] or {}
    lines = [
        "# Flatlandia in the authors' form",
        "",
        "Written by the Flatlandia workflow (`snakemake --cores 2 export`; rule `export_original`, module "
        "`flatlandia.data.original`): the files the fine-localization code of the authors' repository "
        "(github.com/IIT-PAVIS/Flatlandia, `scripts/`) reads, in its schema. Copy `data/*.json` into the `data/` "
        "folder of a clone of that repository. The authors did not publish `flatlandia.json` nor "
        "`region_proposal.json`: both are **regenerated** here from the published reference maps and local "
        "maps (the query poses recovered by registering each GT local map on its reference map). "
        "`local_maps.json` holds the published local maps of these queries, unchanged.",
        "",
        "## data/flatlandia.json",
        "",
        "- `maps[scene].object_list`: the objects' keys (`obj_idx` as text, in `obj_idx` order, so a "
        "proposal's index into it is the object's `obj_idx`); `objects[key].xy`, `objects[key].class` (0..41).",
        "- `maps[scene].queries[token]`: `xy` (the camera), `theta` (degrees, the viewing axis counter-clockwise "
        "from +x of the xy frame), `detected_objects` (the keys of its local map's objects, in the local map's "
        "order).",
        "- **Null**: `detections` (the image boxes: a key per detected object, each null) and `intrinsics` (the "
        "camera): not recoverable from the published data; the fine-localization script does not use them.",
        "- **The frame**: `xy` = (lon, lat) minus the map's centre, times 2 / to_flatlandia "
        f"(to_flatlandia = {TO_FLATLANDIA!r}; the same scale for lon and lat, so one unit is about 188 m "
        "north-south and 111-146 m east-west: not metric). **The normalisation centre** of the original files is "
        "not published; here it is the bounding-box centre of the map's objects, which keeps every map in "
        "(-1, 1). With it, each GT local map of `local_maps.json` is the camera's view of its objects, "
        "R(-theta) (xy_object - xy_camera), to within 1e-9 units (checked when written).",
        f"- **The split** is the workflow's seeded split per scene (seed {md(str(notes['split']['seed']))}, "
        f"train / val / test {md(str(fr.get('train')))} / {md(str(fr.get('val')))} / {md(str(fr.get('test')))}), "
        "**not the original one** (not published): `miscellanea.split.{simple,hard}.{training,validation,testing}`. "
        "`simple`: queries with more than 4 objects (the loader's subset option), `hard`: the others. "
        + ", ".join(
            f"{sub}: {n_q[sub]['training']} / {n_q[sub]['validation']} / {n_q[sub]['testing']}" for sub in SUBSETS
        )
        + " queries.",
        "- `miscellanea.flatlandia_workflow` says the same in the file, with each map's centre and its metric "
        "frame (the workflow's: `crs`, `lon0`, `lat0`), to turn a pose of this frame into metres.",
        "",
        "| map | centre lon | centre lat | objects | queries |",
        "|---|---|---|---|---|",
        centres,
        "",
        "## data/region_proposal.json",
        "",
        "`[GT|depth][all|easy][key][token][0]`: a region as indices into the token's `object_list` (`easy`: the "
        "simple queries). Keys: `CoarseBB`, the oracle GT-BB box (the reference objects inside the axis-aligned "
        "box around the query's matched objects and its camera, enlarged by 10 %; every query, both map types); "
        "the workflow's coarse proposals (GAT retrieval; test split only) under the keys of the same loss and "
        "size: Sim `simil_*`, Trip `triplet_*`, Sim+Trip `mix_*`, with `_nq` = N_LM, `_2nq` = 2N_LM, "
        "`_circle` = R_30. `NoisyGT`, offered by the authors' script, is not defined in the paper: not written. "
        "The authors' script reads the chosen key for every query of every split, so with a coarse key it "
        "needs the training and validation queries' regions too, which the coarse stage does not make.",
        "",
        "Keys present: "
        + "; ".join(f"{md(m)}: " + ", ".join(f"`{md(k)}`" for k in ks) for m, ks in keys.items())
        + ".",
    ]
    if absent:
        lines += [
            "",
            "**Absent**: "
            + ", ".join(f"`{md(s)}`" for s in absent)
            + ": the coarse proposals were not built in this folder when the export was written (`snakemake "
            "--cores 2 benchmark` builds them; then run `snakemake --cores 2 export` again).",
        ]
    return "\n".join(lines) + "\n"
