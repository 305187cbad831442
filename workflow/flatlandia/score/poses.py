"""A poses file read and checked at the door (:func:`read_poses`): CSV (compressed or not) or
Parquet, one row per query, in either pose form, every problem one InputError naming the file and
the rows; :func:`to_metric` turns the geographic form into the scene's metres.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import vocabulary
from flatlandia.plumbing import escape, validate
from flatlandia.plumbing.errors import InputError
from flatlandia.score.scenes import BenchmarkScene

KEYS = ("scene", "token")


#: the two pose forms: the scene's metric frame, or WGS84 with a compass heading
METRIC = ("x_m", "y_m", "theta_deg")


GEOGRAPHIC = ("lon", "lat", "heading_deg")


FORMS = {"metric": METRIC, "geographic": GEOGRAPHIC}


#: a row's setting (its values: flatlandia.vocabulary), and its value when the file has no such column
DEFAULT_MAP_TYPE = "depth"


DEFAULT_PROPOSAL = vocabulary.WHOLE


#: an answer's columns, optional (``flatlandia localize --batch`` writes them): its status (one of
#: vocabulary.STATUSES; the answered are those ``ok``) and its probability of being within (5 m,
#: 5 deg), from 0 to 1; a file without them scores as before (every pose answered, no probability)
STATUS, PROBABILITY = "status", "probability"


#: offending values a message lists
SHOW = 5


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

    @property
    def has_status(self) -> bool:
        """The file says which poses are answered (a ``status`` column)."""
        return STATUS in self.columns

    @property
    def has_probability(self) -> bool:
        """The file gives each pose's probability of being within (5 m, 5 deg)."""
        return PROBABILITY in self.columns


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
            table = validate.read_parquet(  # bounded on what it decodes to, not only on disk
                path, validate.MAX_POSES_ROWS, validate.MAX_POSES_BYTES, "rows", ("MAX_POSES_ROWS", "MAX_POSES_BYTES")
            )
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
    # ASCII digits only: str.isdigit takes '²', which int() refuses (the fuzz suite's find)
    return tuple((0, int(p), "") if p.isascii() and p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", str(s)) if p)


def shortened(text: str) -> str:
    """A cell as an error message quotes it: a long one by its start (:func:`flatlandia.plumbing.validate.shown`)."""
    return text if len(text) <= validate.SHOW_CHARS else validate.shown(text)


def _where(kind: str, i: int) -> str:
    return f"line {i + 2}" if kind == "line" else f"row {i + 1}"


def listing(items, n: int = SHOW) -> str:
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
        + "; ".join(f"scene {shortened(s)}: {listing(validate.shown(token[i]) for i in rows)}" for s, rows in shown)
        + more
        + f" (scene {s0}'s {split} queries are e.g. {', '.join(some) or 'none'})"
        + hint
    )


def _pose_form(raw: pd.DataFrame, cols: list[str], path: Path) -> str:
    """The file's pose form (``metric`` or ``geographic``: :data:`FORMS`), its key columns and the
    form's columns checked: one InputError naming the file for a table without rows, a key column
    missing, both forms, neither, or a form in part."""
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
    return form


def _settings(raw: pd.DataFrame, cols: list[str], kind: str, path: Path) -> dict[str, list]:
    """Per row its ``map_type`` and ``proposal`` (an absent column or an empty cell: the default),
    each checked against the vocabulary's."""
    setting: dict[str, list] = {}
    n = len(raw)
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
                f"unknown {name} {listing(shown)} in {listing(_where(kind, i) for i in bad)}; "
                f"expected one of {', '.join(known)}",
            )
        setting[name] = values
    return setting


def _pose_numbers(raw: pd.DataFrame, form: str, blank: dict, path: Path, label) -> tuple[dict, np.ndarray]:
    """(the form's three columns as numbers, per row whether its pose is left empty: a query without
    a pose); a pose given in part, a cell that is not a finite number, or lon/lat out of range is one
    InputError naming the rows (``label(i)``)."""
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
            f"part of a pose is empty ({holes} in {listing(label(i) for i in partial)}): give "
            f"{', '.join(FORMS[form])} in full, or leave all three empty for a query without a pose",
        )
    numbers = {}
    for c in FORMS[form]:
        values, not_numbers = _numbers(list(raw[c]))
        if not_numbers:
            raise InputError(path, f"{c} is not a number in {listing(label(i) for i in not_numbers)}")
        bad = np.flatnonzero(~np.isfinite(values) & ~no_pose)
        if len(bad):
            raise InputError(
                path,
                f"{c} is not a finite number (NaN, inf) in {listing(label(i) for i in bad)}; a query without "
                "a pose is a row left out or left empty (it counts as a failure)",
            )
        numbers[c] = values
    if form == "geographic":
        for c, lim in (("lon", 180.0), ("lat", 90.0)):
            bad = np.flatnonzero(np.abs(numbers[c]) > lim)
            if len(bad):
                raise InputError(
                    path,
                    f"{c} out of range (|{c}| > {lim:g} degrees) in {listing(label(i) for i in bad)}"
                    + ("; are lon and lat swapped?" if c == "lat" else ""),
                )
    return numbers, no_pose


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
    form = _pose_form(raw, cols, path)

    n = len(raw)
    scene, token = _text(raw["scene"]), _text(raw["token"])
    for name, values in (("scene", scene), ("token", token)):
        empty = [i for i, v in enumerate(values) if v is None]
        if empty:
            raise InputError(path, f"empty {name} in {listing(_where(kind, i) for i in empty)}")

    def label(i: int) -> str:
        return f"{_where(kind, i)} (scene {shortened(scene[i])}, token {shortened(token[i])})"

    setting = _settings(raw, cols, kind, path)
    numbers, no_pose = _pose_numbers(raw, form, blank, path, label)
    seconds = np.full(n, np.nan)
    if "seconds" in cols:
        seconds, not_numbers = _numbers(list(raw["seconds"]))
        bad = sorted(set(not_numbers) | set(np.flatnonzero(np.isinf(seconds) | (seconds < 0))))
        if bad:
            raise InputError(path, f"seconds is not a number >= 0 (or empty) in {listing(label(i) for i in bad)}")

    status, probability = _answers(raw, cols, path, label, no_pose)

    unknown_scenes = sorted({s for s in scene if s not in scenes}, key=_natural)
    if unknown_scenes:
        raise InputError(
            path,
            f"unknown scene(s) {listing(validate.shown(s) for s in unknown_scenes)}; the benchmark's scenes: "
            f"{listing(sorted(scenes, key=_natural), 25)}" + _float_hint(unknown_scenes, "scene ids"),
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
            "status": status,
            "probability": probability,
            "where": [_where(kind, i) for i in range(n)],
        }
    )
    table["no_pose"] = no_pose
    dup = table.duplicated(["scene", "token", "map_type", "proposal"], keep=False)
    if dup.any():
        groups = table[dup].groupby(["scene", "token", "map_type", "proposal"], sort=False)["where"].agg(list)
        shown = [f"scene {s}, token {t}, {m}/{p} ({' and '.join(w)})" for (s, t, m, p), w in groups.items()]
        raise InputError(path, f"duplicate poses of {len(groups)} query(ies) in one setting: {listing(shown, 3)}")

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


def _answers(raw: pd.DataFrame, cols: list[str], path: Path, label, no_pose: np.ndarray) -> tuple[list, np.ndarray]:
    """The rows' status (None where the file has no status column, or for a row without a pose left
    without one) and probability (NaN where not given), checked: a status of
    vocabulary.STATUSES, ``no pose`` only on a row without a pose, a probability from 0 to 1."""
    n = len(raw)
    status: list = [None] * n
    if STATUS in cols:
        status = _text(raw[STATUS])
        bad = [i for i, v in enumerate(status) if v not in vocabulary.STATUSES and not (v is None and no_pose[i])]
        if bad:
            shown = sorted({validate.shown(status[i]) if status[i] else "(empty)" for i in bad})
            raise InputError(
                path,
                f"status {listing(shown)} in {listing(label(i) for i in bad)} is none of "
                f"{', '.join(vocabulary.STATUSES)} (the answers of flatlandia localize)",
            )
        posed = [i for i, v in enumerate(status) if v == vocabulary.NO_POSE and not no_pose[i]]
        if posed:
            raise InputError(
                path,
                f"status {vocabulary.NO_POSE!r} beside a pose in {listing(label(i) for i in posed)}: leave the pose "
                "empty, or give the pose's status",
            )
    probability = np.full(n, np.nan)
    if PROBABILITY in cols:
        probability, not_numbers = _numbers(list(raw[PROBABILITY]))
        bad = sorted(
            set(not_numbers) | set(np.flatnonzero(~(np.isnan(probability) | ((probability >= 0) & (probability <= 1)))))
        )
        if bad:
            raise InputError(
                path, f"probability is not a number from 0 to 1 (or empty) in {listing(label(i) for i in bad)}"
            )
    return status, probability


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
