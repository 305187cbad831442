"""Localize a whole split in one command: ``flatlandia localize --batch SOURCE --out POSES.csv``.

Every query of one split (the test split by default) of an exported benchmark
(``results/export``: its ``{scene}/local_maps.csv``, each scene's ``reference_map.geojson`` and,
as the camera prior, the train split of its ``ground_truth.csv``) or of a finished run
(``results``: each scene's ``queries.parquet`` and ``reference_map.parquet``, with the training
cameras and learned priors the workflow gives the solver) is localized on its scene's map, or on
a city index (``city``), through :func:`flatlandia.localize.localize`: the one-query path of
``flatlandia localize``, which is the solver's path of rule fine_eval. The poses go to a file in
the shape ``flatlandia score`` reads (:data:`POSE_COLUMNS`), so the solver's whole-map rows of
``results/tables/fine_localization.*`` come back from ``flatlandia score`` of that file, and a
method of one's own can start from it.

Why a module of its own: the batch is a loop over :func:`~flatlandia.localize.localize` plus the
readers of the two sources; the one-query path stays the one place a pose is computed.
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import paths, vocabulary
from flatlandia.classes import CLASSES
from flatlandia.localize import gps_fixes, maps, query_files, solve
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.names import plain_name

#: the poses file's columns: what ``flatlandia score`` reads (scene, token, the metric pose, the
#: setting, the query time, the answer's status and calibrated probability of being within (5 m,
#: 5 deg): the answered share is counted from them), then what the answer adds (ignored by score):
#: found, the answer's confidence, its best alternative (pose and probability; empty when none),
#: the scene the pose lies in (a city can put a query in another scene) and why a query got no pose
POSE_COLUMNS = ["scene", "token", "x_m", "y_m", "theta_deg", "map_type", "proposal", "seconds", "status", "probability"]
ALTERNATIVE_COLUMNS = ["alt_x_m", "alt_y_m", "alt_theta_deg", "alt_probability"]
EXTRA_COLUMNS = ["found", "confidence", *ALTERNATIVE_COLUMNS, "located_scene", "reason"]
#: the alternatives a query's answer is asked for: the best one goes to the file (the ranking of
#: the best pose does not depend on it)
ALTERNATIVES = 1
#: the proposal a batch searches by default: the whole map (the score's setting ``whole``); the
#: others (vocabulary.PROPOSALS) are the map regions of rule fine_eval (``gtbb``, the oracle box;
#: ``coarse-*``, a coarse stage's proposals), searched row for row as it searches them
PROPOSAL = vocabulary.WHOLE


#: the columns of a fixes file (a phone's fix per query); the compass pair is optional
FIX_COLUMNS = ["scene", "token", "lon", "lat", "sigma_m"]
COMPASS_COLUMNS = ["compass_deg", "compass_sigma_deg"]
SPLITS = ("train", "val", "test")


# ----------------------------------------------------------------------------- sources


@dataclass
class Source:
    """Where the queries of a batch come from: an export folder or a results folder."""

    kind: str  # "export" or "results"
    root: Path
    scenes: list[str]
    cities: dict = field(default_factory=dict)  # scene -> city name

    def queries(self, scene: str, split: str, map_type: str) -> list[query_files.Query]:
        """The ``split`` queries of a scene as localize reads them (id: the token), in the source's order."""
        if self.kind == "results":
            return _results_queries(self.root, scene, split, map_type)
        return _export_queries(self.root, scene, split, map_type)

    def proposals(self, scene: str, split: str, map_type: str, proposal: str) -> tuple[dict, str | None]:
        """(token -> the proposed objects' obj_idx in proposed order, the coarse strategy used) of a
        scene's ``split`` queries: a run's proposals through rule fine_eval's function
        (:func:`flatlandia.proposals.for_queries`), an export's from its proposals.csv. The coarse
        strategy is the fine table's (else the default config's), as ``flatlandia score`` takes it."""
        from flatlandia import score

        strategy = None
        if proposal in vocabulary.COARSE_PROPOSALS:
            table = paths.within(self.root, paths.table("fine_localization")) if self.kind == "results" else None
            builtin = _results_table(table) if table is not None and table.is_file() else None
            strategy = score.builtin_setting(builtin, proposal) or score.default_strategy(proposal)
        if self.kind == "results":
            return _results_proposals(self.root, scene, split, map_type, proposal, strategy), strategy
        path = self.root / scene / "proposals.csv"
        props = _read_csv(path, ["token", "map_type", "source", "strategy", "obj_idx"])
        props = props[
            (props["source"] == proposal)
            & (props["map_type"] == map_type)
            & (props["strategy"] == (strategy or vocabulary.ORACLE_STRATEGY))
        ]
        if proposal != vocabulary.GTBB and not len(props):
            raise InputError(
                path, f"no {proposal} proposals ({strategy}, {map_type}): the export was written without them"
            )
        out: dict[str, list[int]] = {}
        for t, o in zip(props["token"], _cells(props, "obj_idx", path, integer=True), strict=True):
            out.setdefault(t, []).append(int(o))
        return out, strategy

    def scene_map(self, scene: str, learned, settings=None, proposal: str = PROPOSAL) -> maps.SceneMap:
        """The scene's map with what the source gives the solver: a run's reference_map.parquet with
        its training cameras and learned priors (``learned`` "auto": those rule fine_eval reads for
        ``proposal``, paths.proposal_priors); an export's reference_map.geojson with the cameras of its
        ground_truth.csv's train split (learned priors only where ``learned`` names a file)."""
        if self.kind == "results":
            if learned == "auto":
                learned = paths.within(self.root, paths.proposal_priors(proposal))
                learned = learned if learned.is_file() else None
            return maps.load_map(paths.within(self.root, paths.reference_map(scene)), settings, learned)
        folder = self.root / scene
        m = maps.load_map(folder / "reference_map.geojson", settings, None if learned == "auto" else learned)
        maps.set_training_priors(
            m, _export_training(folder / "ground_truth.csv", m.obj_idx), folder / "ground_truth.csv"
        )
        m.scene, m.cities = scene, dict(self.cities)
        return m


def open_source(path: str | Path) -> Source:
    """An export folder (``scenes.csv`` and one folder per scene) or a results folder (its benchmark
    record, ``tables/dataset_stats_per_scene.parquet``); InputError naming the folder otherwise."""
    from flatlandia import score

    root = Path(path)
    if not root.is_dir():
        raise InputError(root, "not a folder: --batch takes an export (results/export) or a results folder")
    if (root / "scenes.csv").is_file():
        scenes = _read_csv(root / "scenes.csv", ["scene", "city"])
        return Source("export", root, scenes["scene"].tolist(), dict(zip(scenes["scene"], scenes["city"], strict=True)))
    record = root / score.BENCHMARK_RECORD
    if record.is_file():
        table = validate.read_table(record, validate.MAX_SCENES, validate.MAX_MAP_BYTES, columns=["scene"])
        ids = [plain_name(str(s), record, "scene id") for s in table["scene"]]  # ids become paths
        return Source("results", root, ids, maps.scene_cities(root))
    raise InputError(
        root,
        f"neither an export (no scenes.csv: `snakemake --cores 2 export` writes results/export) nor a results "
        f"folder (no {score.BENCHMARK_RECORD}: `snakemake --cores 2 benchmark`)",
    )


def _read_csv(path: Path, columns: list[str]) -> pd.DataFrame:
    """A CSV of the export (every cell as text), with ``columns`` checked."""
    if not path.exists():
        raise InputError(path, "missing: the export is incomplete (`snakemake --cores 2 export` writes it again)")
    data = validate.read_bytes(path, validate.MAX_CSV_BYTES, "MAX_CSV_BYTES")  # a regular file, bounded
    try:
        df = pd.read_csv(BytesIO(data), dtype=str, keep_default_na=False)
    except Exception as e:
        raise InputError(path, f"cannot be read as CSV ({type(e).__name__})") from None
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(path, f"missing column(s) {', '.join(missing)}")
    return df


#: a number in an export's cell: ASCII digits, a point, an exponent (nan and inf read, then refused
#: as not finite); pandas' float() would also take ``1_000`` and full-width or Arabic-Indic digits
FLOAT_CELL = re.compile(
    r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE
)
#: an id or a count in an export's cell: an int64 (a 20-digit id was an OverflowError)
INT_CELL = re.compile(r"-?\d{1,18}", re.ASCII)


def _cells(df: pd.DataFrame, column: str, path: Path, integer: bool = False) -> np.ndarray:
    """A column of an export's CSV (text cells) as numbers; InputError naming the file, the row
    (the first after the header is row 1) and the column of the first cell that is not one."""
    pattern = INT_CELL if integer else FLOAT_CELL
    values = [str(v).strip() for v in df[column]]
    for i, v in enumerate(values):
        if not pattern.fullmatch(v):
            kind = "an integer of at most 18 digits" if integer else "a number"
            raise InputError(path, f"row {i + 1}, column {column}: {validate.shown(v)} is not {kind}")
    return np.array([int(v) for v in values] if integer else [float(v) for v in values], np.int64 if integer else float)


def _results_table(
    path: Path, max_rows: int = validate.MAX_POSES_ROWS, max_bytes: int = validate.MAX_POSES_BYTES
) -> pd.DataFrame:
    """A table of a results folder given to --batch (a user's, as --map is), through the Parquet door."""
    return validate.read_table(path, max_rows, max_bytes)


def _results_queries(results: Path, scene: str, split: str, map_type: str) -> list[query_files.Query]:
    from flatlandia.data import localmaps

    path = paths.within(results, paths.queries(scene))
    if not path.is_file():
        raise InputError(path, "missing: run the workflow first (`snakemake --cores 2 benchmark`)")
    q = _results_table(path, validate.MAX_QUERIES, validate.MAX_QUERY_TABLE_BYTES)
    validate.columns(q, ("token", "split", "classes"), path)
    q = q[q["split"] == split]
    out = []
    for r in q.itertuples(index=False):
        try:
            xy, cls = localmaps.local_map(r, map_type), np.asarray(r.classes, np.int64)
        except (AttributeError, TypeError, ValueError, OverflowError):
            raise InputError(
                path, f"query {validate.shown(r.token)}: its local map or classes are not numbers"
            ) from None
        validate.local_map(np.asarray(xy, float), cls, path, f"query {validate.shown(r.token)}", len(CLASSES))
        out.append(query_files.Query(str(r.token), xy, cls, str(path)))
    return out


def _results_proposals(
    results: Path, scene: str, split: str, map_type: str, proposal: str, strategy: str | None
) -> dict[str, list[int]]:
    from flatlandia import proposals

    ref = _results_table(
        paths.within(results, paths.reference_map(scene)), validate.MAX_MAP_OBJECTS, validate.MAX_MAP_BYTES
    )
    q = _results_table(
        paths.within(results, paths.queries(scene)), validate.MAX_QUERIES, validate.MAX_QUERY_TABLE_BYTES
    )
    coarse = None
    if vocabulary.coarse_source(proposal):
        path = paths.within(results, paths.proposal_table(proposal))
        if not path.is_file():
            raise InputError(path, f"missing: the {proposal} proposals (`snakemake --cores 2 {path}`)")
        coarse = _results_table(path)
    props = proposals.for_queries(ref, q[q["split"] == split], proposal, map_type, coarse, strategy)
    return {str(t): [int(o) for o in p] for t, p in zip(props["token"], props["proposal"])}


def _export_queries(export: Path, scene: str, split: str, map_type: str) -> list[query_files.Query]:
    path = export / scene / "local_maps.csv"
    tokens = _read_csv(export / scene / "queries.csv", ["token", "split"])
    tokens = tokens.loc[tokens["split"] == split, "token"].tolist()
    lm = _read_csv(path, ["token", "map_type", "k", "class_id", "x", "y"])
    k, cls = _cells(lm, "k", path, integer=True), _cells(lm, "class_id", path, integer=True)
    xy = np.column_stack([_cells(lm, "x", path), _cells(lm, "y", path)]).reshape(-1, 2)
    mine = (lm["map_type"] == map_type).to_numpy()
    lm, k, cls, xy = lm[mine], k[mine], cls[mine], xy[mine]
    rows = {}
    for i, t in enumerate(lm["token"]):
        rows.setdefault(t, []).append(i)
    out = []
    for t in tokens:
        idx = np.array(rows.get(t, []), int)
        if len(idx) == 0:
            raise InputError(path, f"query {t} ({split} in queries.csv) has no {map_type} local map")
        idx = idx[np.argsort(k[idx], kind="stable")]
        validate.local_map(xy[idx], cls[idx], path, f"query {validate.shown(t)}", len(CLASSES))
        out.append(query_files.Query(t, xy[idx], cls[idx], str(path)))
    return out


def _export_training(path: Path, obj_idx: np.ndarray) -> pd.DataFrame:
    """An export's ground_truth.csv as the solver's priors read a queries table: the train split's
    cameras (``x_m``, ``y_m``, ``theta_deg``) and the reference objects each saw (``ref_idx``),
    through the door of a queries table (:func:`flatlandia.plumbing.validate.ground_truth`: every
    row's camera finite and within its bounds, every id one of the map's ``obj_idx``)."""
    gt = _read_csv(path, ["token", "split", "x_m", "y_m", "theta_deg", "matched_obj_idx"])
    table = pd.DataFrame(
        {
            "token": gt["token"].to_numpy(),
            "split": gt["split"].to_numpy(),
            **{c: _cells(gt, c, path) for c in ("x_m", "y_m", "theta_deg")},
            "ref_idx": [_ids(cell, path, i) for i, cell in enumerate(gt["matched_obj_idx"])],
        }
    )
    validate.ground_truth(
        table, path, lambda i: f"row {i + 1} (token {validate.shown(table['token'].iat[i])})", obj_idx
    )
    return table[table["split"] == "train"].drop(columns="token").reset_index(drop=True)


def _ids(cell: str, path: Path, i: int) -> np.ndarray:
    """The object ids of a ground_truth.csv cell (``matched_obj_idx``: integers apart by spaces)."""
    ids = str(cell).split()
    bad = next((v for v in ids if not INT_CELL.fullmatch(v)), None)
    if bad is not None:
        raise InputError(
            path, f"row {i + 1}, column matched_obj_idx: {validate.shown(bad)} is not an integer of at most 18 digits"
        )
    return np.array([int(v) for v in ids], np.int64)


# ----------------------------------------------------------------------------- fixes


def read_fixes(path: str | Path) -> dict[tuple[str, str], tuple[tuple, tuple | None]]:
    """A fixes file (CSV: ``scene``, ``token``, ``lon``, ``lat``, ``sigma_m``; optional
    ``compass_deg``, ``compass_sigma_deg``): (scene, token) -> (gps, compass) as
    :func:`flatlandia.localize.localize` takes them. A query without a row is localized without a
    fix. Every problem is one InputError naming the file and the line."""
    path = Path(path)
    df = _read_csv(path, FIX_COLUMNS)
    compass = all(c in df.columns for c in COMPASS_COLUMNS)
    out = {}
    for i, r in enumerate(df.to_dict("records")):
        where = f"line {i + 2} (scene {r['scene']}, token {r['token']})"
        try:
            lon, lat, sigma = (float(r[c]) for c in ("lon", "lat", "sigma_m"))
            heading = (float(r["compass_deg"]), float(r["compass_sigma_deg"])) if compass and r["compass_deg"] else None
        except ValueError:
            raise InputError(path, f"{where}: lon, lat, sigma_m (and a compass pair) must be numbers") from None
        try:
            gps_fixes.check_prior((lon, lat, sigma), heading)
        except InputError as e:
            raise InputError(path, f"{where}: {e.problem}") from None
        key = (str(r["scene"]), str(r["token"]))
        if key in out:
            raise InputError(path, f"{where}: a second fix of the same query")
        out[key] = ((lon, lat, sigma), heading)
    return out


# ----------------------------------------------------------------------------- the batch


@dataclass
class Batch:
    """A batch's poses (one row per query, :data:`POSE_COLUMNS` + :data:`EXTRA_COLUMNS`; no pose:
    empty pose cells, a failure to ``flatlandia score``) and its notes for the terminal."""

    poses: pd.DataFrame
    notes: list[str]
    warnings: list[str]

    def describe(self) -> str:
        p = self.poses
        found = int(p["found"].sum())
        line = f"{len(p)} queries, {found} localized, {len(p) - found} without a pose"
        answered = int((p["status"] == vocabulary.ANSWERED).sum())
        if found:
            line += f" ({answered} answered, status {vocabulary.ANSWERED}; {found - answered} {vocabulary.AMBIGUOUS})"
        moved = p["found"] & p["located_scene"].notna() & (p["located_scene"] != p["scene"])
        if moved.any():
            line += f", {int(moved.sum())} placed in another scene than their own"
        sec = p["seconds"].to_numpy(float)
        return line + (f"; median {1000 * np.median(sec):.1f} ms per query" if len(sec) else "")


def _terminal_progress(total: int, desc: str) -> Callable[[Iterable], Iterable] | None:
    """A tqdm bar on stderr when it is a terminal; nothing otherwise (a log stays clean), nor where
    tqdm is not installed (it comes with the workflow's extras, not with the localizer alone)."""
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    bar = tqdm(total=total, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), unit="query")

    def wrap(items):
        for x in items:
            yield x
            bar.update(1)
        bar.refresh()

    wrap.close = bar.close  # type: ignore[attr-defined]
    return wrap


def localize_batch(
    source: str | Path | Source,
    split: str = "test",
    map_type: str = "depth",
    city: str | Path | None = None,
    fixes: dict | None = None,
    learned: str | Path | None = "auto",
    settings=None,
    progress: bool = True,
    proposal: str = PROPOSAL,
) -> Batch:
    """Every ``split`` query of ``source`` (:func:`open_source`) localized by
    :func:`flatlandia.localize.localize` on its scene's map (or on the ``city`` index), with a fix
    where ``fixes`` (:func:`read_fixes`) has one; the poses in each query's own scene frame.
    ``proposal``: the whole map, or each query's proposed map region (``gtbb``, ``coarse-*``; a
    scene map, no fixes), searched as rule fine_eval searches it."""
    if split not in SPLITS:
        raise InputError("--split", f"{split!r} is not one of {', '.join(SPLITS)}")
    if map_type not in vocabulary.MAP_TYPES:
        raise InputError("--map-type", f"{map_type!r} is not one of {', '.join(vocabulary.MAP_TYPES)}")
    if proposal not in vocabulary.PROPOSALS:
        raise InputError("--proposal", f"{proposal!r} is not one of {', '.join(vocabulary.PROPOSALS)}")
    if proposal != PROPOSAL and (city is not None or fixes):
        raise InputError("--proposal", "a proposal is searched on each scene's map: not with a city index or fixes")
    src = source if isinstance(source, Source) else open_source(source)
    fixes = fixes or {}
    work = [(s, src.queries(s, split, map_type)) for s in src.scenes]  # every file read before any solve
    unknown = sorted(set(fixes) - {(s, q.id) for s, qs in work for q in qs})
    if unknown:
        shown = ", ".join(f"scene {s} token {t}" for s, t in unknown[:3])
        raise InputError("--fixes", f"{len(unknown)} fix(es) of queries not in the {split} split: {shown}")
    cmap = maps.load_map(city, settings, learned) if city is not None else None
    if cmap is not None and not cmap.tiled:
        raise InputError(city, "--city takes a city index (results/city/{n}/index), not a scene map")
    regions = {s: src.proposals(s, split, map_type, proposal) for s, _ in work} if proposal != PROPOSAL else {}
    notes = [f"source: {src.kind} folder {src.root}, {sum(len(q) for _, q in work)} {split} queries ({map_type})"]
    if regions:
        strategy = next(iter(regions.values()))[1]
        notes.append(f"each query searched on its {proposal} proposal" + (f" ({strategy})" if strategy else ""))
    if src.kind == "export" and learned == "auto" and map_type == "depth":
        notes.append(
            "an export holds no learned priors: depth maps are solved without the scale prior and verifier of the "
            f"workflow's run (give --priors {paths.proposal_priors(proposal)} for the benchmark's solver)"
        )
    total = sum(len(q) for _, q in work)
    bar = _terminal_progress(total, "localize") if progress else None
    rows, warnings, warm = [], [], False
    t0 = time.perf_counter()
    for scene, queries in work:
        if not queries:
            continue
        m = cmap if cmap is not None else src.scene_map(scene, learned, settings, proposal)
        pos = {int(o): k for k, o in enumerate(m.obj_idx)}

        def answer(q, m=m, pos=pos, scene=scene):
            gps, compass = fixes.get((scene, q.id), (None, None))
            region = None
            if regions:  # the proposal's objects, in proposed order (a query without one: none)
                region = np.array([pos[o] for o in regions[scene][0].get(q.id, []) if o in pos], np.int64)
            return solve.localize(m, q, map_type, alternatives=ALTERNATIVES, gps=gps, compass=compass, rows=region)

        if not warm:
            _warm_up(answer, queries[0])
            warm = True
        for q in bar(queries) if bar else queries:
            a = answer(q)
            warnings += a.get("warnings", [])
            rows.append(_row(m, scene, q.id, map_type, a, proposal))
    if bar:
        bar.close()
    notes.append(f"localized in {time.perf_counter() - t0:.1f} s wall (maps loaded per scene)")
    poses = pd.DataFrame(rows, columns=POSE_COLUMNS + EXTRA_COLUMNS)
    return Batch(poses, notes, list(dict.fromkeys(warnings)))


def _warm_up(answer: Callable[[query_files.Query], dict], query: query_files.Query) -> None:
    """Solve the batch's first query once, untimed, before any query is timed, so that no query's
    ``seconds`` holds the solver's compilation. Why not :func:`flatlandia.solver.warm_up` alone
    (load_map calls it): it compiles the plain solver on a made-up problem, not the kernels of the
    learned priors (verifier, likelihood), the camera seeds or the city search, which numba compiled
    inside the first query's seconds (8.5 s with an empty numba cache; 20 s in issue 45). The first
    query asked as it will be asked runs the kernels its path runs."""
    answer(query)


def _row(m: maps.ObjectMap, scene: str, token: str, map_type: str, answer: dict, proposal: str) -> dict:
    """One query's row of the poses file: its pose and its best alternative's in its own scene's
    frame (a city's pose moved out of the tiled frame by its scene's tile), empty where it has none;
    its status and probability as the answer gives them (:func:`flatlandia.localize.answer_status`)."""
    x, y, theta = _scene_pose(m, scene, answer) if answer["found"] else (None, None, None)
    alts = answer["alternatives"][:1]
    alt = [*_scene_pose(m, scene, alts[0]), alts[0]["probability"]] if alts else [None] * 4
    return {
        "scene": scene,
        "token": token,
        "x_m": x,
        "y_m": y,
        "theta_deg": theta,
        "map_type": map_type,
        "proposal": proposal,
        "seconds": answer["seconds"],
        "status": answer["status"],
        "probability": answer["probability"],
        "found": bool(answer["found"]),
        "confidence": answer["confidence"],
        **dict(zip(ALTERNATIVE_COLUMNS, alt, strict=True)),
        "located_scene": answer.get("scene"),
        "reason": answer.get("reason", ""),
    }


def _scene_pose(m: maps.ObjectMap, scene: str, pose: dict) -> tuple:
    """(x_m, y_m, theta_deg) of an answer's pose (or an alternative's) in ``scene``'s own frame;
    Nones where the city has no tile of that scene."""
    xy = m.scene_xy(scene, pose["x_m"], pose["y_m"])
    return (None, None, None) if xy is None else (*xy, pose["theta_deg"])


def write_poses(batch: Batch, path: str | Path, *, reads=(), artifacts=()) -> Path:
    """The poses file (``.csv``: floats exact, scene and token as text; or ``.parquet``), written
    atomically through the write door (``reads``, ``artifacts``: what it must not replace,
    :func:`flatlandia.plumbing.files.check_target`): the shape ``flatlandia score`` reads."""
    from flatlandia.data import export
    from flatlandia.plumbing import files

    path = Path(path)
    df = batch.poses.copy()
    for c in ("x_m", "y_m", "theta_deg", "probability", *ALTERNATIVE_COLUMNS):
        df[c] = df[c].astype(float)
    if path.suffix.lower() == ".parquet":
        files.write_parquet(df, path, {"written_by": "flatlandia localize --batch"}, reads=reads, artifacts=artifacts)
    elif path.suffix.lower() == ".csv":
        files.write_text(export.csv_text(df), path, reads=reads, artifacts=artifacts)
    else:
        raise InputError(path, "a poses file is .csv or .parquet")
    return path


def check_out(path: str | Path) -> None:
    """The poses file's name, checked before any work: ``.csv`` or ``.parquet`` (where it may be
    written is the write door's: the command checks it with the inputs it reads)."""
    if Path(path).suffix.lower() not in (".csv", ".parquet"):
        raise InputError(path, "a poses file is .csv or .parquet (--out POSES.csv)")
