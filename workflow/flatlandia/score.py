"""Score your own poses: an external method's poses of the benchmark's queries, scored exactly as
the built-in methods are (``flatlandia score``, rule ``external_eval``).

A poses file (CSV or Parquet) has one row per query: ``scene``, ``token`` and one pose form,
either ``x_m, y_m, theta_deg`` (the scene's metric frame: x east, y north, metres; the viewing
axis counter-clockwise from east, degrees) or ``lon, lat, heading_deg`` (WGS84 degrees and a
compass heading, clockwise from north: heading = 90 - theta). Optional columns: ``map_type``
(``gt`` or ``depth``, default ``depth``), ``proposal`` (``gtbb``, ``whole``, ``coarse-sim``,
``coarse-trip``, ``coarse-simtrip``, ``coarse-solver``; default ``whole``) name the setting a row
was computed in (one run per setting; an empty cell takes the default), ``seconds`` its query time
(empty: unknown). Other columns are ignored. A query without a pose is a row left out, or one whose
three pose cells are empty (CSV) or null (Parquet), as ``poses_template.csv`` of the export comes.

Why the same functions: a row of an external run must read against the solver's and the learned
models' rows, so it is built by :func:`flatlandia.fine.evaluation.error_row` (errors by
:func:`flatlandia.geo.pose_errors`) and summarised by :func:`flatlandia.fine.evaluation.summarise`;
a query without a pose is a failure exactly as the solver's (no pose: infinite error, 180 deg).
Every problem of a file is one :class:`flatlandia.plumbing.errors.InputError` naming the file; what looks
like a convention mix-up (lon/lat swapped, radians for degrees) is a warning, not an error.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, paper, paths, vocabulary
from flatlandia import proposals as proposals_module
from flatlandia.fine import evaluation
from flatlandia.plumbing import escape, files, validate
from flatlandia.plumbing.errors import InputError

KEYS = ("scene", "token")
#: the two pose forms: the scene's metric frame, or WGS84 with a compass heading
METRIC = ("x_m", "y_m", "theta_deg")
GEOGRAPHIC = ("lon", "lat", "heading_deg")
FORMS = {"metric": METRIC, "geographic": GEOGRAPHIC}
#: a row's setting (its values: flatlandia.vocabulary), and its value when the file has no such column
DEFAULT_MAP_TYPE = "depth"
DEFAULT_PROPOSAL = vocabulary.WHOLE
#: an external method's name: a plain lowercase id that is no built-in method's slug
#: (vocabulary.METHODS; it becomes results/external/{name}_{map_type}_{proposal}/, paths.external_run)
NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
#: offending values a message lists
SHOW = 5
#: plausibility: a fix that makes the median error this many times smaller is reported ...
FAR_SMALLER = 5.0
#: ... when the median errors as given are at least this large (m, deg): a good method is never
#: suspected, and an honest poor one is not made 5 times better by a swap or a unit
IMPLAUSIBLE_M = 5.0
IMPLAUSIBLE_DEG = 20.0
#: metric positions this far from the truth (median) look like another frame (UTM, lon/lat...)
ANOTHER_FRAME_M = 10_000.0


def check_name(name: str, source: str = "--name") -> str:
    """An external method's name, refused (InputError naming ``source``) unless it is a plain
    lowercase id that is not a built-in method's slug."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise InputError(
            source,
            f"name {name!r} is refused: a method name is a lowercase letter, then letters, digits or '_' (at most 40)",
        )
    if vocabulary.is_builtin(name):
        raise InputError(
            source, f"name {name!r} is a built-in method's ({', '.join(vocabulary.METHODS)}): pick another"
        )
    return name


def external_entries(entries: list[dict]) -> list[dict]:
    """Config ``external`` with each entry's defaults filled in from the schema (``map_types``,
    ``proposals``); a name given twice is refused (:class:`flatlandia.config.ConfigError`)."""
    from flatlandia import config

    item = config.schema()["properties"]["external"]["items"]["properties"]
    defaults = {k: v["default"] for k, v in item.items() if "default" in v}
    out, seen = [], set()
    for k, e in enumerate(entries or []):
        if e["name"] in seen:
            raise config.ConfigError(f"'external.{k}.name': {e['name']!r} is the name of an earlier entry")
        seen.add(e["name"])
        out.append({**defaults, **e})
    return out


# ----------------------------------------------------------------------------- the benchmark


@dataclass(frozen=True)
class BenchmarkScene:
    """One benchmark scene as scoring needs it: its reference map, its queries (every split) and
    its metric frame (None for a map without GPS)."""

    scene: str
    ref: pd.DataFrame
    queries: pd.DataFrame
    frame: geo.MetricFrame | None


def read_scene(reference_map: str | Path, queries: str | Path) -> BenchmarkScene:
    """A scene from the workflow's files: results/{scene}/maps/reference_map.parquet (its frame in
    the Parquet metadata ``flatlandia``) and results/{scene}/queries/queries.parquet."""
    for p in (reference_map, queries):
        if not Path(p).exists():
            raise InputError(p, "missing: run the workflow first (`snakemake --cores 2 benchmark`)")
    meta = files.read_parquet_metadata(reference_map)
    ref, q = pd.read_parquet(reference_map), pd.read_parquet(queries)
    scene = str(meta.get("scene", ref["scene"].iloc[0] if len(ref) else ""))
    frame = geo.MetricFrame(float(meta["lon0"]), float(meta["lat0"])) if meta.get("lon0") is not None else None
    return BenchmarkScene(scene, ref, q, frame)


#: the record of the scenes the benchmark in a results folder was built on, in that folder
#: (paths.BENCHMARK_RECORD; common.smk reads it too)
BENCHMARK_RECORD = str(paths.within("", paths.BENCHMARK_RECORD))


def results_scenes(results: str | Path) -> dict[str, BenchmarkScene]:
    """The benchmark scenes of a results folder (those of its ``tables/dataset_stats_per_scene.parquet``)."""
    results = Path(results)
    record = results / BENCHMARK_RECORD
    if not record.exists():
        raise InputError(
            record,
            "missing: the benchmark's scenes are read from it (build the benchmark first: `snakemake --cores 2 benchmark`)",
        )
    ids = [str(s) for s in pd.read_parquet(record, columns=["scene"])["scene"]]
    return {
        s: read_scene(paths.within(results, paths.reference_map(s)), paths.within(results, paths.queries(s)))
        for s in ids
    }


# ----------------------------------------------------------------------------- reading a poses file


@dataclass
class Poses:
    """A validated poses file: one row per (scene, token, map_type, proposal) of the split that has
    a pose, in the scene's metric frame (``x_m, y_m, theta_deg``), with the file's own values
    (``a, b, angle``: the pose columns as given) and where each row is in the file (``where``)."""

    path: str
    form: str
    table: pd.DataFrame
    columns: list[str]
    #: the (map_type, proposal) settings of its rows of the split, in order of first appearance
    #: (a setting whose rows are all empty is scored: every query a failure)
    held: list[tuple[str, str]]
    outside_split: int = 0
    split: str = "test"
    notes: list[str] = field(default_factory=list)

    def settings(self) -> list[tuple[str, str]]:
        return list(self.held)


def _read_table(path: Path) -> tuple[pd.DataFrame, str, dict[str, np.ndarray]]:
    """The file's rows (CSV: every cell as text), how its rows are named ('line' or 'row') and,
    per column, which cells are blank (CSV: empty; Parquet: null)."""
    if not path.exists() and not path.is_symlink():
        raise InputError(path, "no such file")
    validate.regular_file(path, validate.MAX_POSES_BYTES, "MAX_POSES_BYTES")  # a pipe or device: never opened
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes[-1:] in ([".parquet"], [".pq"]):
        kind, fmt = "row", "Parquet"
    elif suffixes[-1:] == [".csv"] or suffixes[-2:] in ([".csv", ".gz"], [".csv", ".bz2"], [".csv", ".xz"]):
        kind, fmt = "line", "CSV"
    else:
        raise InputError(
            path, f"unknown format {''.join(path.suffixes) or '(no suffix)'!r}: a poses file is .csv or .parquet"
        )
    try:
        if fmt == "Parquet":
            import pyarrow.parquet as pq

            validate.parquet_size(
                path, validate.MAX_POSES_ROWS, validate.MAX_POSES_BYTES, "rows", ("MAX_POSES_ROWS", "MAX_POSES_BYTES")
            )
            table = pq.read_table(path)
            df = table.to_pandas()
            # a null cell is blank (no value); a NaN is a value, and not a finite one
            blank = {name: np.asarray(table.column(name).is_null(), bool) for name in table.column_names}
            return df, kind, blank
        df = pd.read_csv(_csv_bytes(path), dtype=str, keep_default_na=False, skipinitialspace=True)
        validate.count(len(df), validate.MAX_POSES_ROWS, path, "rows", "MAX_POSES_ROWS")
        return df, kind, {name: (df[name].str.strip() == "").to_numpy(bool) for name in df.columns}
    except InputError:
        raise
    except pd.errors.EmptyDataError:
        raise InputError(path, "empty file: expected a header line (scene,token,...) and one row per query") from None
    except Exception as e:  # a file that is not what its suffix says (pyarrow's, pandas' parser errors)
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(path, f"cannot be read as {fmt}: {first}") from None


#: how a compressed poses CSV is opened, by its last suffix
_DECOMPRESS = {".gz": "gzip", ".bz2": "bz2", ".xz": "lzma"}


def _csv_bytes(path: Path):
    """A poses CSV's bytes, as a file object: read at most :data:`flatlandia.plumbing.validate.MAX_POSES_BYTES`,
    a compressed one decompressed as a stream and stopped there (a 4 MB archive of 2 GB of rows is
    refused after 64 MB, never held whole)."""
    import importlib
    import io as _io

    module = _DECOMPRESS.get(path.suffix.lower())
    if module:
        opener = importlib.import_module(module).open
        data = validate.read_decompressed(path, opener, validate.MAX_POSES_BYTES, "MAX_POSES_BYTES")
    else:
        data = validate.read_bytes(path, validate.MAX_POSES_BYTES, "MAX_POSES_BYTES")
    return _io.BytesIO(data)


def _natural(s: str) -> tuple:
    """Scene ids in natural order (2 before 10)."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", str(s)) if p)


def _short(text: str) -> str:
    """A cell as an error message quotes it: a long one by its start (:func:`flatlandia.plumbing.validate.shown`)."""
    return text if len(text) <= validate.SHOW_CHARS else validate.shown(text)


def _where(kind: str, i: int) -> str:
    return f"line {i + 2}" if kind == "line" else f"row {i + 1}"


def _listing(items, n: int = SHOW) -> str:
    items = list(items)
    more = f" and {len(items) - n} more" if len(items) > n else ""
    return ", ".join(str(x) for x in items[:n]) + more


def _text(values) -> list:
    """Cells as stripped text (None for an empty or missing cell); a cell the export made safe for
    spreadsheets (``'=x``, :func:`flatlandia.plumbing.escape.csv_cell`) is read back as its value."""
    out = []
    for v in values:
        if v is None or (isinstance(v, float) and math.isnan(v)):
            out.append(None)
            continue
        if isinstance(v, (int, np.integer)):
            v = int(v)
        s = escape.csv_cell_read(str(v).strip())
        out.append(s or None)
    return out


#: a number as a CSV cell holds it: ASCII digits, a point, an exponent (or nan/inf, refused as not
#: finite); Python's float() would also take ``1_000`` and full-width digits, which no CSV means
NUMBER_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE)


def _numbers(values) -> tuple[np.ndarray, list[int]]:
    """Cells as floats (NaN for an empty cell) and the positions of cells that are not numbers
    (text that is not a plain decimal number: :data:`NUMBER_RE`)."""
    out = np.full(len(values), np.nan)
    bad = []
    for i, v in enumerate(values):
        if v is None or (isinstance(v, str) and not v.strip()):
            continue
        if isinstance(v, (bool, np.bool_)) or (isinstance(v, str) and not NUMBER_RE.fullmatch(v.strip())):
            bad.append(i)
            continue
        try:
            out[i] = float(v)
        except (TypeError, ValueError, OverflowError):
            bad.append(i)
    return out, bad


#: a number written by a float reader: a decimal point or an exponent (tokens and scene ids are
#: digits, or text; '198666222125904.0', '1.98666222125904e+14' are a token read as a float)
FLOAT_LIKE = re.compile(r"^[+-]?(\d+\.\d*|\.\d+|\d+(\.\d*)?[eE][+-]?\d+)$")


def _float_hint(values, what: str) -> str:
    """A hint when ``values`` look like numbers a CSV reader turned into floats ('' otherwise)."""
    floaty = [v for v in values if FLOAT_LIKE.match(str(v))]
    if not floaty or len(floaty) < len(list(values)) / 2:
        return ""
    return (
        f"; the {what} look like numbers read as floats (e.g. {validate.shown(floaty[0])}): read the CSV with dtype=str, "
        "e.g. pd.read_csv(path, dtype={'scene': str, 'token': str}), before writing the poses"
    )


def _unknown_tokens(unknown: list[int], scene: list, token: list, split_of: dict, split: str) -> str:
    """One line on the tokens that are none of their scene's queries: how many, a few of the first
    scenes', an example of the right ones and, when they look like floats, why."""
    by_scene: dict[str, list[int]] = {}
    for i in unknown:
        by_scene.setdefault(scene[i], []).append(i)
    s0 = next(iter(by_scene))
    some = [t for t, sp in split_of[s0].items() if sp == split][:3]
    shown = list(by_scene.items())[:3]
    more = f"; and {len(by_scene) - len(shown)} more scene(s)" if len(by_scene) > len(shown) else ""
    hint = _float_hint([token[i] for i in unknown], "tokens")
    return (
        f"{len(unknown)} unknown token(s) in {len(by_scene)} scene(s): "
        + "; ".join(f"scene {_short(s)}: {_listing(validate.shown(token[i]) for i in rows)}" for s, rows in shown)
        + more
        + f" (scene {s0}'s {split} queries are e.g. {', '.join(some) or 'none'})"
        + hint
    )


def read_poses(path: str | Path, scenes: dict[str, BenchmarkScene], split: str = "test") -> Poses:
    """Read and check a poses file against the benchmark's ``scenes``; every problem is one
    :class:`InputError` naming the file. Poses of the scenes' queries outside ``split`` are kept
    out (counted in ``outside_split``). Geographic poses are turned into the scenes' metric frames
    (theta = 90 - heading in the frame's grid: within a scene its north is true north to a few
    thousandths of a degree).
    """
    path = Path(path)
    raw, kind, blank = _read_table(path)
    blank = {str(c).strip(): v for c, v in blank.items()}
    raw = raw.rename(columns=lambda c: str(c).strip())
    cols = list(raw.columns)
    if not len(raw):
        raise InputError(path, "holds no poses (a header and no rows)")
    missing = [c for c in KEYS if c not in cols]
    forms_hint = "either x_m, y_m, theta_deg (metric frame) or lon, lat, heading_deg (compass heading)"
    if missing:
        raise InputError(
            path, f"missing column(s) {', '.join(missing)}: a poses file has scene, token and {forms_hint}"
        )
    present = {f: [c for c in cs if c in cols] for f, cs in FORMS.items()}
    given = [f for f, cs in present.items() if cs]
    if len(given) == 2:
        both = present["metric"] + present["geographic"]
        raise InputError(path, f"both pose forms ({', '.join(both)}): give {forms_hint}, not both")
    if not given:
        raise InputError(path, f"no pose columns: give {forms_hint}")
    form = given[0]
    lacking = [c for c in FORMS[form] if c not in cols]
    if lacking:
        raise InputError(path, f"missing column(s) {', '.join(lacking)} of the pose form {', '.join(FORMS[form])}")

    n = len(raw)
    scene, token = _text(raw["scene"]), _text(raw["token"])
    for name, values in (("scene", scene), ("token", token)):
        empty = [i for i, v in enumerate(values) if v is None]
        if empty:
            raise InputError(path, f"empty {name} in {_listing(_where(kind, i) for i in empty)}")

    def label(i: int) -> str:
        return f"{_where(kind, i)} (scene {_short(scene[i])}, token {_short(token[i])})"

    setting = {}
    for name, known, default in (
        ("map_type", vocabulary.MAP_TYPES, DEFAULT_MAP_TYPE),
        ("proposal", tuple(vocabulary.PROPOSALS), DEFAULT_PROPOSAL),
    ):
        if name not in cols:
            setting[name] = [default] * n
            continue
        values = [default if v is None else v for v in _text(raw[name])]  # an empty cell: the default
        bad = [i for i, v in enumerate(values) if v not in known]
        if bad:
            shown = sorted({validate.shown(values[i]) for i in bad})
            raise InputError(
                path,
                f"unknown {name} {_listing(shown)} in {_listing(_where(kind, i) for i in bad)}; "
                f"expected one of {', '.join(known)}",
            )
        setting[name] = values

    # a row whose pose cells are all blank (a template row left empty) is a query without a pose,
    # as a row left out; a pose given in part is refused
    empty = np.column_stack([blank[c] for c in FORMS[form]])
    no_pose = empty.all(axis=1)
    partial = np.flatnonzero(empty.any(axis=1) & ~no_pose)
    if len(partial):
        i = partial[0]
        holes = ", ".join(c for c, e in zip(FORMS[form], empty[i]) if e)
        raise InputError(
            path,
            f"part of a pose is empty ({holes} in {_listing(label(i) for i in partial)}): give "
            f"{', '.join(FORMS[form])} in full, or leave all three empty for a query without a pose",
        )
    numbers = {}
    for c in FORMS[form]:
        values, not_numbers = _numbers(list(raw[c]))
        if not_numbers:
            raise InputError(path, f"{c} is not a number in {_listing(label(i) for i in not_numbers)}")
        bad = np.flatnonzero(~np.isfinite(values) & ~no_pose)
        if len(bad):
            raise InputError(
                path,
                f"{c} is not a finite number (NaN, inf) in {_listing(label(i) for i in bad)}; a query without "
                "a pose is a row left out or left empty (it counts as a failure)",
            )
        numbers[c] = values
    if form == "geographic":
        for c, lim in (("lon", 180.0), ("lat", 90.0)):
            bad = np.flatnonzero(np.abs(numbers[c]) > lim)
            if len(bad):
                raise InputError(
                    path,
                    f"{c} out of range (|{c}| > {lim:g} degrees) in {_listing(label(i) for i in bad)}"
                    + ("; are lon and lat swapped?" if c == "lat" else ""),
                )
    seconds = np.full(n, np.nan)
    if "seconds" in cols:
        seconds, not_numbers = _numbers(list(raw["seconds"]))
        bad = sorted(set(not_numbers) | set(np.flatnonzero(np.isinf(seconds) | (seconds < 0))))
        if bad:
            raise InputError(path, f"seconds is not a number >= 0 (or empty) in {_listing(label(i) for i in bad)}")

    unknown_scenes = sorted({s for s in scene if s not in scenes}, key=_natural)
    if unknown_scenes:
        raise InputError(
            path,
            f"unknown scene(s) {_listing(validate.shown(s) for s in unknown_scenes)}; the benchmark's scenes: "
            f"{_listing(sorted(scenes, key=_natural), 25)}" + _float_hint(unknown_scenes, "scene ids"),
        )
    split_of = {s: dict(zip(b.queries["token"].astype(str), b.queries["split"].astype(str))) for s, b in scenes.items()}
    unknown = [i for i in range(n) if token[i] not in split_of[scene[i]]]
    if unknown:
        raise InputError(path, _unknown_tokens(unknown, scene, token, split_of, split))

    table = pd.DataFrame(
        {
            "scene": scene,
            "token": token,
            "map_type": setting["map_type"],
            "proposal": setting["proposal"],
            "a": numbers[FORMS[form][0]],
            "b": numbers[FORMS[form][1]],
            "angle": numbers[FORMS[form][2]],
            "seconds": seconds,
            "where": [_where(kind, i) for i in range(n)],
        }
    )
    table["no_pose"] = no_pose
    dup = table.duplicated(["scene", "token", "map_type", "proposal"], keep=False)
    if dup.any():
        groups = table[dup].groupby(["scene", "token", "map_type", "proposal"], sort=False)["where"].agg(list)
        shown = [f"scene {s}, token {t}, {m}/{p} ({' and '.join(w)})" for (s, t, m, p), w in groups.items()]
        raise InputError(path, f"duplicate poses of {len(groups)} query(ies) in one setting: {_listing(shown, 3)}")

    inside = np.array([split_of[s][t] == split for s, t in zip(table["scene"], table["token"])], bool)
    if not inside.any():
        raise InputError(path, f"none of its {n} rows is of a {split} query (the benchmark scores the {split} split)")
    if not (inside & ~no_pose).any():
        raise InputError(path, f"holds no pose: every row of a {split} query is empty (fill in its pose columns)")
    settings = list(dict.fromkeys(zip(table.loc[inside, "map_type"], table.loc[inside, "proposal"])))
    table = table[inside & ~no_pose].drop(columns="no_pose").reset_index(drop=True)
    x, y, theta = to_metric(table, form, scenes, path)
    table["x_m"], table["y_m"], table["theta_deg"] = x, y, theta
    poses = Poses(str(path), form, table, cols, settings, int((~inside).sum()), split)
    if poses.outside_split:
        poses.notes.append(
            f"{poses.outside_split} of its {n} rows are of queries outside the {split} split: not scored"
        )
    empty_rows = int((inside & no_pose).sum())
    if empty_rows:
        poses.notes.append(f"{empty_rows} of its rows have no pose (left empty): failures, as queries left out")
    return poses


def to_metric(table: pd.DataFrame, form: str, scenes: dict[str, BenchmarkScene], path) -> tuple[np.ndarray, ...]:
    """The file's poses (columns a, b, angle) as x_m, y_m, theta_deg in each scene's metric frame."""
    a, b, angle = (table[c].to_numpy(float) for c in ("a", "b", "angle"))
    if form == "metric":
        return a.copy(), b.copy(), angle.copy()
    x, y = np.full(len(table), np.nan), np.full(len(table), np.nan)
    for s, rows in table.groupby("scene", sort=False).indices.items():
        frame = scenes[s].frame
        if frame is None:
            raise InputError(path, f"scene {s}'s map has no geographic frame (no GPS): give x_m, y_m, theta_deg")
        xy = frame.to_xy(np.column_stack([a[rows], b[rows]]))
        x[rows], y[rows] = xy[:, 0], xy[:, 1]
    return x, y, 90.0 - angle


# ----------------------------------------------------------------------------- scoring


def errors_table(
    poses: Poses,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
) -> pd.DataFrame:
    """One run's errors table (rule fine_eval's columns, :func:`evaluation.error_row`): a row per
    ``split`` query of every scene, in the solver's order; the file's pose of that query in this
    (map_type, proposal) setting, or a failure (no pose: infinite error, 180 deg) where it has none.
    The proposal gives the row's proposal size and solvability (F%), as for the built-in runs."""
    mine = poses.table[(poses.table["map_type"] == map_type) & (poses.table["proposal"] == proposal)]
    pose_of = {
        (s, t): (x, y, th, sec)
        for s, t, x, y, th, sec in mine[["scene", "token", "x_m", "y_m", "theta_deg", "seconds"]].itertuples(
            index=False
        )
    }
    label = vocabulary.strategy_label(proposal, strategy)
    rows = []
    for b in scenes.values():
        ref, q = b.ref, b.queries
        test = q[q["split"] == poses.split]
        props = proposals_module.for_queries(ref, test, proposal, map_type, coarse, strategy)
        prop_of = {str(t): p for t, p in zip(props["token"], props["proposal"])}
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
        ref_cls = ref["class_id"].to_numpy()
        lat = float(ref["lat"].mean())
        for r in test.itertuples(index=False):
            idx = np.array([pos[int(o)] for o in prop_of.get(str(r.token), []) if int(o) in pos], int)
            given = pose_of.get((str(r.scene), str(r.token)))
            if given is None:
                pose, errors, seconds = (np.nan, np.nan, np.nan), (np.inf, 180.0), np.nan
            else:
                x, y, th, seconds = given
                pose = (x, y, math.radians(th))
                errors = geo.pose_errors(x, y, pose[2], r.x_m, r.y_m, math.radians(r.theta_deg))
            rows.append(
                evaluation.error_row(
                    r,
                    method=name,
                    map_type=map_type,
                    strategy=label,
                    proposal_classes=ref_cls[idx],
                    lat=lat,
                    pose=pose,
                    errors=errors,
                    fit=(float("nan"), 0, 0),
                    seconds=seconds,
                    cpu_seconds=float("nan"),
                )
            )
    return pd.DataFrame(rows)


def run_summary(
    errors: pd.DataFrame,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    strategy: str | None,
    poses: Poses,
) -> dict:
    """Rule fine_eval's summary of a run (:func:`evaluation.summarise` and the same keys), with
    how many queries the file gave a pose (``scored``) and how many it left out (``missing``)."""
    out = evaluation.summarise(errors)
    scored = int(np.isfinite(errors["x"].to_numpy(float)).sum()) if len(errors) else 0
    out.update(
        method=name,
        method_slug=name,
        map_type=map_type,
        proposal=proposal,
        strategy=vocabulary.strategy_label(proposal, strategy),
        run=f"{name}_{map_type}_{proposal}",
        ref_map_kb=float(np.mean([evaluation.ref_map_kb(b.ref) for b in scenes.values()])) if scenes else float("nan"),
        train_s=0.0,
        epochs=0,
        trained_on="",
        external=True,
        poses=poses.path,
        pose_form=poses.form,
        split=poses.split,
        scored=scored,
        missing=int(len(errors) - scored),
    )
    return out


@dataclass
class Run:
    """One scored setting of an external method: its errors table and summary."""

    name: str
    map_type: str
    proposal: str
    errors: pd.DataFrame
    summary: dict

    @property
    def run(self) -> str:
        return f"{self.name}_{self.map_type}_{self.proposal}"

    def metadata(self) -> dict:
        """The errors table's Parquet metadata (rule fine_eval's keys)."""
        return {
            "run": self.run,
            "method": self.name,
            "map_type": self.map_type,
            "proposal": self.proposal,
            "solver": None,
            "model_config": None,
            "external": True,
            "poses": self.summary["poses"],
        }

    def write(self, errors_path: str | Path, summary_path: str | Path) -> None:
        files.write_parquet(self.errors, errors_path, self.metadata())
        files.write_json(evaluation.json_safe(self.summary), summary_path)

    def describe(self) -> str:
        """One paragraph for the terminal: queries, scored, missing, medians, recalls."""
        s = self.summary

        def f(v, spec):
            return "–" if v is None or not np.isfinite(v) else format(v, spec)

        rm = " / ".join(f(s[c], ".1f") for c in evaluation.RECALL_COLUMNS[: len(evaluation.RECALL_M)])
        rd = " / ".join(f(s[c], ".1f") for c in evaluation.RECALL_COLUMNS[len(evaluation.RECALL_M) :])
        ms = " / ".join(f"{m:g}" for m in evaluation.RECALL_M)
        ds = " / ".join(f"{d:g}" for d in evaluation.RECALL_DEG)
        return (
            f"{self.run} ({self.map_type} local maps, {s['strategy']} proposals): {s['queries']} {s['split']} queries, "
            f"{s['scored']} scored, {s['missing']} missing (failures); median {f(s['median_m'], '.2f')} m, "
            f"{f(s['median_deg'], '.2f')} deg; recall {ms} m: {rm} %; {ds} deg: {rd} %; "
            f"{f(s[evaluation.WITHIN_COLUMN], '.1f')} % within ({evaluation.WITHIN[0]:g} m, {evaluation.WITHIN[1]:g} deg)"
        )


def score_run(
    poses: Poses,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
) -> Run:
    """One (map_type, proposal) setting of a poses file, scored."""
    errors = errors_table(poses, scenes, name, map_type, proposal, coarse, strategy)
    return Run(name, map_type, proposal, errors, run_summary(errors, scenes, name, map_type, proposal, strategy, poses))


def external_run(
    path: str | Path,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    split: str = "test",
) -> tuple[Run, list[str]]:
    """Rule external_eval: one setting of the poses file at ``path``, scored, and the warnings
    (plausibility, poses outside the split). A file without a pose in this setting is refused."""
    check_name(name, "config external")
    poses = read_poses(path, scenes, split)
    if (map_type, proposal) not in poses.settings():
        held = ", ".join(f"{m}/{p}" for m, p in poses.settings())
        raise InputError(
            path,
            f"no poses for map_type {map_type}, proposal {proposal} (the file's settings: {held}; a file without "
            f"a map_type column is {DEFAULT_MAP_TYPE}, without a proposal column {DEFAULT_PROPOSAL})",
        )
    return score_run(poses, scenes, name, map_type, proposal, coarse, strategy), poses.notes + plausibility(
        poses, scenes
    )


# ----------------------------------------------------------------------------- plausibility


def _truth(poses: Poses, scenes: dict[str, BenchmarkScene]) -> pd.DataFrame:
    """Each pose row's true pose (gx, gy, gtheta_deg)."""
    parts = []
    for s, b in scenes.items():
        q = b.queries[["token", "x_m", "y_m", "theta_deg"]].rename(
            columns={"x_m": "gx", "y_m": "gy", "theta_deg": "gtheta"}
        )
        parts.append(q.assign(scene=s, token=q["token"].astype(str)))
    truth = (
        pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["scene", "token", "gx", "gy", "gtheta"])
    )
    return poses.table.merge(truth, on=["scene", "token"], how="left")


#: a pose is suspected of a unit or order mix-up only when it is this far from its truth (metres):
#: an honest pose a few metres off, near the line x = y, must not read as swapped
ROW_IMPLAUSIBLE_M = 20.0
#: a pose this far outside its scene (the box around its map objects and query cameras), metres, is
#: nowhere a method could have put it from that map
EXTENT_MARGIN_M = 500.0


def scene_extents(scenes: dict[str, BenchmarkScene]) -> dict[str, tuple[float, float, float, float]]:
    """Per scene the box (x0, y0, x1, y1) in its metric frame around its reference objects and every
    query camera, grown by :data:`EXTENT_MARGIN_M`: where a pose of that scene can be."""
    out = {}
    for s, b in scenes.items():
        xy = np.vstack(
            [
                b.ref[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2),
                b.queries[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2),
            ]
        )
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            lo, hi = xy.min(axis=0) - EXTENT_MARGIN_M, xy.max(axis=0) + EXTENT_MARGIN_M
            out[s] = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    return out


def _readings(t: pd.DataFrame, form: str, scenes: dict[str, BenchmarkScene], path) -> dict[str, tuple]:
    """The pose rows read the ways a file's units or order are mixed up: reason -> (x, y) per row
    in the scene frame (NaN where that reading gives no position)."""
    a, b = t["a"].to_numpy(float), t["b"].to_numpy(float)
    if form == "metric":
        ways = {
            "x_m, y_m look like kilometres (the columns are metres)": (a * 1000.0, b * 1000.0),
            "x_m and y_m look swapped (x_m is east, y_m north)": (b, a),
            "x_m, y_m look like kilometres and swapped": (b * 1000.0, a * 1000.0),
        }
        return ways
    ways = {
        "lon and lat look swapped (lon is longitude, lat latitude)": (b, a),
        "lon, lat look like radians (the columns are degrees)": (np.degrees(a), np.degrees(b)),
        "lon, lat look like radians and swapped": (np.degrees(b), np.degrees(a)),
    }
    out = {}
    for why, (la, lb) in ways.items():
        x, y = np.full(len(t), np.nan), np.full(len(t), np.nan)
        ok = (np.abs(la) <= 180) & (np.abs(lb) <= 90)
        for sc, rows in t[ok].groupby("scene", sort=False).indices.items():
            frame = scenes[sc].frame
            if frame is None:
                continue
            idx = np.flatnonzero(ok)[rows]
            with np.errstate(all="ignore"):
                xy = frame.to_xy(np.column_stack([la[idx], lb[idx]]))
            x[idx], y[idx] = xy[:, 0], xy[:, 1]
        out[why] = (x, y)
    return out


def row_plausibility(poses: Poses, scenes: dict[str, BenchmarkScene]) -> list[str]:
    """Pose by pose, against its scene (:func:`scene_extents`): a pose outside the scene's extent looks
    wrong, and so does one that a mixed-up unit or order (kilometres, x/y or lon/lat swapped, lon/lat
    in radians, :func:`_readings`) explains: read that way it lies in the scene, closer to its truth
    than as given, and as given it is outside the scene, or within the scene shrunk 1000 times
    around its origin (kilometres), or :data:`ROW_IMPLAUSIBLE_M` from its truth while read that way
    it is within :data:`IMPLAUSIBLE_M` and :data:`FAR_SMALLER` times closer. Some such rows: a warning naming them (returned); most of them
    (over half): InputError, the file is not scored."""
    t = _truth(poses, scenes)
    if not len(t):
        return []
    x, y = t["x_m"].to_numpy(float), t["y_m"].to_numpy(float)
    gx, gy = t["gx"].to_numpy(float), t["gy"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        err = np.hypot(x - gx, y - gy)
    box = scene_extents(scenes)
    ext = np.array([box.get(sc, (-np.inf, -np.inf, np.inf, np.inf)) for sc in t["scene"]], float).reshape(-1, 4)

    def inside(px, py, shrink: float = 1.0):
        with np.errstate(invalid="ignore"):
            return (
                (px >= ext[:, 0] / shrink)
                & (py >= ext[:, 1] / shrink)
                & (px <= ext[:, 2] / shrink)
                & (py <= ext[:, 3] / shrink)
            )

    outside = ~inside(x, y)
    at_origin = inside(x, y, 1000.0)  # where a pose in kilometres lands
    reason = np.array(["" for _ in range(len(t))], dtype=object)
    best = np.full(len(t), np.inf)
    for why, (rx, ry) in _readings(t, poses.form, scenes, poses.path).items():
        with np.errstate(invalid="ignore"):
            e = np.hypot(rx - gx, ry - gy)
            telling = outside | ((err > ROW_IMPLAUSIBLE_M) & (e * FAR_SMALLER < err) & (e <= IMPLAUSIBLE_M))
            if "kilometres" in why:
                telling |= at_origin
            fixes = inside(rx, ry) & (e < err) & telling & (e < best)
        reason[fixes], best[fixes] = why, e[fixes]
    far = outside & (reason == "")
    with np.errstate(invalid="ignore"):
        km = np.hypot(
            np.maximum(ext[:, 0] - x, x - ext[:, 2]).clip(0), np.maximum(ext[:, 1] - y, y - ext[:, 3]).clip(0)
        )
    reason[far] = [f"{d / 1000:.4g} km outside the scene" for d in km[far]]
    wrong = np.flatnonzero(reason != "")
    if not len(wrong):
        return []
    name = Path(poses.path).name
    groups: dict[str, list[str]] = {}
    for i in wrong:
        why = "outside the scene" if far[i] else str(reason[i])
        detail = f" ({reason[i]})" if far[i] else ""
        label = f"{t['where'].iloc[i]} (scene {_short(t['scene'].iloc[i])}, token {_short(t['token'].iloc[i])}){detail}"
        groups.setdefault(why, []).append(label)
    what = f"{len(wrong)} of its {len(t)} poses look wrong for their scene: " + "; ".join(
        f"{why}: {_listing(rows, 3)}" for why, rows in groups.items()
    )
    hint = (
        " (x_m, y_m: metres in the scene's own frame, transverse Mercator centred on the scene, lon0/lat0 in its "
        "reference map's metadata; lon, lat: degrees)"
    )
    if 2 * len(wrong) > len(t):
        raise InputError(poses.path, f"{what}{hint}; fix the file: nothing was scored")
    return [f"{name}: {what}{hint}; scored as given"]


def plausibility(poses: Poses, scenes: dict[str, BenchmarkScene], min_poses: int = 3) -> list[str]:
    """Warnings (text, not errors) where the poses look like a convention mixed up: swapping
    lon/lat (or x_m/y_m) gives far smaller position errors; reading the angles as radians (or as
    degrees converted twice), or as the other angle convention (compass heading vs counter-clockwise
    from east), gives far smaller heading errors; positions kilometres off (another frame)."""
    rows = row_plausibility(poses, scenes)  # most rows wrong: InputError
    t = _truth(poses, scenes)
    if len(t) < min_poses:
        return rows
    gt = t[["gx", "gy"]].to_numpy(float)
    g_theta = np.radians(t["gtheta"].to_numpy(float))
    x, y, theta = (t[c].to_numpy(float) for c in ("x_m", "y_m", "theta_deg"))
    e_m, e_deg = geo.pose_errors(x, y, np.radians(theta), gt[:, 0], gt[:, 1], g_theta)
    med_m, med_deg = float(np.median(e_m)), float(np.median(e_deg))
    out = list(rows)
    name = Path(poses.path).name
    cols = FORMS[poses.form]
    if med_m > IMPLAUSIBLE_M:
        swapped = t.assign(a=t["b"], b=t["a"])
        try:
            sx, sy, _ = to_metric(swapped, poses.form, scenes, poses.path)
        except InputError:
            sx = sy = np.full(len(t), np.nan)
        with np.errstate(invalid="ignore"):
            s_m = float(np.median(np.hypot(sx - gt[:, 0], sy - gt[:, 1])))
        if np.isfinite(s_m) and s_m * FAR_SMALLER < med_m:
            out.append(
                f"{name}: {cols[0]} and {cols[1]} look swapped: swapped, the median position error would be "
                f"{s_m:.2f} m instead of {med_m:.4g} m ({cols[0]} is {'longitude' if poses.form == 'geographic' else 'east'}, "
                f"{cols[1]} {'latitude' if poses.form == 'geographic' else 'north'})"
            )
        elif poses.form == "metric" and med_m > ANOTHER_FRAME_M:
            out.append(
                f"{name}: the positions are {med_m / 1000:.4g} km from the truth (median): x_m, y_m are metres in the "
                "scene's own frame (transverse Mercator centred on the scene, lon0/lat0 in its reference map's "
                "metadata), not UTM or lon/lat; for lon/lat give lon, lat, heading_deg instead"
            )
    if med_deg > IMPLAUSIBLE_DEG:
        angle = t["angle"].to_numpy(float)
        to_theta = (lambda v: 90.0 - v) if poses.form == "geographic" else (lambda v: v)
        other = "counter-clockwise from east (theta)" if poses.form == "geographic" else "a compass heading"
        # the unit mix-ups only where the values show it: radians within a turn of 2 pi, degrees
        # converted twice beyond a turn of 360
        turn = float(np.max(np.abs(angle)))
        fixes = [
            (np.degrees(angle), "radians (the column is degrees)", turn <= 2 * np.pi + 1e-6),
            (np.radians(angle), "degrees converted to degrees twice (read as radians)", turn > 360.0),
            (90.0 - angle, other, True),
        ]
        best = None
        for v, what, possible in fixes:
            if not possible:
                continue
            d = float(np.median(geo.pose_errors(x, y, np.radians(to_theta(v)), gt[:, 0], gt[:, 1], g_theta)[1]))
            if d * FAR_SMALLER < med_deg and (best is None or d < best[0]):
                best = (d, what)
        if best:
            out.append(
                f"{name}: the {cols[2]} values look like {best[1]}: read so, the median heading error would be "
                f"{best[0]:.2f} deg instead of {med_deg:.2f} deg ({cols[2]} is degrees, "
                + ("clockwise from north" if poses.form == "geographic" else "counter-clockwise from east")
                + ")"
            )
    return out


# ----------------------------------------------------------------------------- the command


def builtin_setting(table: pd.DataFrame | None, proposal: str) -> str | None:
    """The coarse strategy of the built-in runs of ``proposal`` in a fine table (its label is
    '{loss label} {strategy}'), None where the table has none."""
    if table is None or proposal not in vocabulary.COARSE_PROPOSALS:
        return None
    rows = table[table["proposal"] == proposal]
    prefix = vocabulary.COARSE_PROPOSALS[proposal] + " "
    labels = [s for s in rows["strategy"].astype(str) if s.startswith(prefix)]
    return labels[0][len(prefix) :] if labels else None


def default_strategy(proposal: str) -> str | None:
    """The default config's strategy of a coarse proposal table, picked by the key rule fine_eval
    reads for it (vocabulary.coarse_strategy: fine.coarse_strategy, or coarse.solver.fine_strategy
    for the solver's proposals); None for a map region."""
    from flatlandia import config

    return vocabulary.coarse_strategy(proposal, config.section_defaults())


@dataclass
class Scores:
    """``flatlandia score``'s result: the runs, the warnings, the built-in table beside them."""

    runs: list[Run]
    warnings: list[str]
    builtin: pd.DataFrame | None
    notes: list[str]


def score_file(path: str | Path, name: str, results: str | Path, split: str = "test") -> Scores:
    """Every setting of a poses file scored against a results folder's benchmark (nothing written)."""
    check_name(name)
    results = Path(results)
    scenes = results_scenes(results)
    poses = read_poses(path, scenes, split)
    table_path = paths.within(results, paths.table("fine_localization"))
    builtin = pd.read_parquet(table_path) if table_path.exists() else None
    notes = list(poses.notes)
    if builtin is None:
        notes.append(f"no built-in table at {table_path}: scores.md lists only {name}'s rows")
    runs = []
    for map_type, proposal in poses.settings():
        coarse = strategy = None
        if vocabulary.coarse_source(proposal):
            coarse_path = paths.within(results, paths.proposal_table(proposal))
            if not coarse_path.exists():
                raise InputError(
                    coarse_path, f"missing: the {proposal} proposals are needed to score {map_type}/{proposal}"
                )
            coarse = pd.read_parquet(coarse_path)
            strategy = builtin_setting(builtin, proposal) or default_strategy(proposal)
        runs.append(score_run(poses, scenes, name, map_type, proposal, coarse, strategy))
    return Scores(runs, plausibility(poses, scenes), builtin, notes)


#: the columns of scores.md: what the run is, then every threshold and recall, failures
#: (the README's headline, % within (5 m, 5°), among the paper's thresholds in their order)
SCORE_COLUMNS = (
    ["queries", "median_m", "median_deg"]
    + evaluation.THRESHOLD_COLUMNS[:2]
    + [evaluation.WITHIN_COLUMN]
    + evaluation.THRESHOLD_COLUMNS[2:]
    + evaluation.RECALL_COLUMNS
    + ["no_pose_pct", "failure_pct", "gross_pct"]
)


def scores_markdown(scores: Scores, name: str, poses_path: str) -> str:
    """scores.md: per setting, the method's row beside the built-in rows of the same map type
    and proposal (every threshold and recall column)."""
    from flatlandia.fine import table as fine_table

    thresholds = [f"{m:g} m & {d:g}°" for m, d in paper.THRESHOLDS]
    heads = (
        ["queries", "median m", "median °"]
        + thresholds[:2]
        + ["{:g} m & {:g}°".format(*evaluation.WITHIN)]
        + thresholds[2:]
        + [f"recall {m:g} m" for m in evaluation.RECALL_M]
        + [f"recall {d:g}°" for d in evaluation.RECALL_DEG]
        + ["no pose %", "F %", "gross %"]
    )
    out = [
        f"# Scores of {escape.markdown(name)}",
        "",
        f"Poses: `{escape.markdown(poses_path)}`, scored on the {escape.markdown(scores.runs[0].summary['split'])} split "
        "with the built-in methods' functions (true metres; queries without a pose are failures: infinite error, "
        "180°). Threshold columns: % of queries under both the position and the heading threshold; recalls: "
        "position and heading apart.",
        "",
    ]
    for note in scores.notes:
        out += [f"Note: {escape.markdown(note)}", ""]
    for w in scores.warnings:
        out += [f"**Warning**: {escape.markdown(w)}", ""]
    for run in scores.runs:
        s = run.summary
        mine = fine_table.table_rows([s])
        rows = [mine]
        if scores.builtin is not None:
            same = scores.builtin[
                (scores.builtin["map_type"] == run.map_type) & (scores.builtin["proposal"] == run.proposal)
            ]
            rows.append(same)
        df = pd.concat(rows, ignore_index=True)
        out += [
            f"## {escape.markdown(run.map_type)} local maps, {escape.markdown(s['strategy'])} proposals",
            "",
            f"{s['queries']} queries, {s['scored']} scored, {s['missing']} missing (failures).",
            "",
            "| method | " + " | ".join(heads) + " |",
            "|---|" + "---|" * len(heads),
        ]
        for r in df.to_dict("records"):
            cells = []
            for c in SCORE_COLUMNS:
                v = r[c]
                if c == "queries":
                    cells.append(str(int(v)))
                else:
                    cells.append(
                        "–" if v is None or not np.isfinite(v) else f"{v:.2f}" if c.startswith("median") else f"{v:.1f}"
                    )
            method = escape.markdown(r["method_label"]) + (" (yours)" if r["run"] == run.run else "")
            out.append(f"| {method} | " + " | ".join(cells) + " |")
        if len(df) == 1:
            out += ["", "No built-in run of this setting in the results folder."]
        out.append("")
    return "\n".join(out)


def write_scores(scores: Scores, name: str, poses_path: str, out: str | Path) -> list[Path]:
    """Write each run's errors.parquet and summary.json (rule fine_eval's shapes) under
    ``out/{name}_{map_type}_{proposal}/`` and ``out/scores.md``; the paths written."""
    out = Path(out)
    written = []
    for run in scores.runs:
        folder = out / run.run
        run.write(folder / "errors.parquet", folder / "summary.json")
        written += [folder / "errors.parquet", folder / "summary.json"]
    files.write_text(scores_markdown(scores, name, poses_path), out / "scores.md")
    return written + [out / "scores.md"]
