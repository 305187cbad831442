"""The fuzz suite's tools (tests/test_fuzz_doors.py): Hypothesis profiles, the budgets one reading
must stay within, hostile values, mutations of valid files (JSON trees, bytes, tables, zip members)
and the special files a path can name.

Why a module of its own: every door of docs/security.md is fuzzed the same way (a valid file built
as the workflow writes it, then mutated; the reader must return a checked object or raise the
project's own error, in bounded time and memory, writing nothing), so the mutations and the budget
are written once. ``benchmarks/fuzz_doors.py`` loads this module as a pytest plugin (``-p
fuzz_strategies``) so that ``--hypothesis-profile=long`` finds the profiles registered before pytest
configures Hypothesis; ``HYPOTHESIS_PROFILE=long`` selects it as well.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import resource
import signal
import tempfile
import time
import unicodedata
import zipfile
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st
from hypothesis.configuration import set_hypothesis_home_dir

# Hypothesis caches what it learns of Unicode and of the code's constants in ./.hypothesis even
# without an example database: kept in the temporary folder instead, never in the checkout
if not os.environ.get("HYPOTHESIS_STORAGE_DIRECTORY"):
    set_hypothesis_home_dir(Path(tempfile.gettempdir()) / f"hypothesis-flatlandia-{os.getuid()}")

# ----------------------------------------------------------------------------- profiles

#: examples per door in each profile (a door's weight scales it: a door whose one example costs
#: 50 ms gets fewer than one of a millisecond); "fast" is the fast lane's (deterministic, the whole
#: module in about two minutes on two cores), "long" the benchmark's (at least 20,000 over all doors)
EXAMPLES = {"fast": 200, "long": 1500}
#: CPU seconds one reading may take (measured around the door's call, not the building of its file:
#: CPU time, not wall time, so that a machine shared with other jobs does not make it flaky; a
#: reading of the poses door took 2.2 s of CPU in the whole suite on the busy 2-core machine, well
#: under 1 s alone: a budget that catches a blow-up, not the machine's load); a reading that blocks
#: (a FIFO) is stopped by :data:`HARD_STOP_S`
MAX_CPU_S = 5.0
#: Hypothesis' own phases, without "explain" (it reruns a failure many times over to comment it)
PHASES = (Phase.explicit, Phase.reuse, Phase.generate, Phase.target, Phase.shrink)

settings.register_profile(
    "fast",
    max_examples=EXAMPLES["fast"],
    deadline=None,  # the door's own time is bounded (MAX_CPU_S), not the building of its file
    phases=PHASES,
    derandomize=True,
    database=None,
    print_blob=False,
    # the strategies build files from large valid seeds (a map, a checkpoint): a few examples of
    # them take longer to generate than Hypothesis expects of a strategy
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile(
    "long",
    max_examples=EXAMPLES["long"],
    deadline=None,
    phases=PHASES,
    derandomize=False,
    database=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def profile_name() -> str:
    """The profile in force: ``--hypothesis-profile`` when one was given, else ``HYPOTHESIS_PROFILE``,
    else "fast"."""
    chosen = settings.get_current_profile_name()
    if chosen in EXAMPLES:
        return chosen
    return os.environ.get("HYPOTHESIS_PROFILE") or "fast"


def door_settings(weight: float = 1.0) -> settings:
    """The settings of one door's test: the profile's, with ``weight`` times its examples."""
    name = profile_name()
    base = settings.get_profile(name)
    return settings(base, max_examples=max(10, int(EXAMPLES.get(name, EXAMPLES["fast"]) * weight)))


# ----------------------------------------------------------------------------- budgets

#: resident memory one reading may add to the test process at its peak (megabytes): the process holds
#: about 0.6 GB with torch, numba and pyarrow loaded, so this is a peak RSS of about 1.5 GB; a valid
#: file of the doors adds a few MB. Measured from the RSS at the reading's start, not as an absolute
#: peak: what an earlier failing example left behind (Hypothesis keeps its traceback) is not this one's
MAX_ADDED_MB = 900
#: the address space a reading may add before an allocation fails (a bomb that no check stops is
#: caught by MAX_ADDED_MB on its way; this keeps the machine safe from the rest of it)
ADDRESS_HEADROOM = 3 * 1024**3
#: seconds after which a reading is stopped (SIGALRM): far past the deadline, so a reading that
#: would run for an hour (a YAML alias bomb walked node by node) ends as a failure, not a hung suite
HARD_STOP_S = 20


class Overrun(BaseException):
    """Raised by the alarm inside a reading that ran past :data:`HARD_STOP_S` (a BaseException: no
    ``except Exception`` of a reader turns it into its own error)."""


def _status_kb(key: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def _reset_peak() -> None:
    """Reset the process's peak RSS (Linux: ``clear_refs`` 5), so that it measures one reading."""
    with contextlib.suppress(OSError):
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")


def peak_rss_mb() -> float:
    """Peak resident memory since the last reset, MB (``VmHWM``; ``ru_maxrss`` where there is none)."""
    kb = _status_kb("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024


def _on_alarm(signum, frame):
    raise Overrun


def listing(folder: Path) -> set[str]:
    """Every path under ``folder`` (links not followed), relative to it."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(folder):
        out |= {os.path.relpath(os.path.join(dirpath, n), folder) for n in dirnames + filenames}
    return out


@contextlib.contextmanager
def bounded(watch: tuple[Path, ...] = ()):
    """One reading within the budgets: at most :data:`MAX_CPU_S` of CPU and :data:`MAX_ADDED_MB` of
    peak RSS added, stopped after
    :data:`HARD_STOP_S` (an AssertionError then, which Hypothesis shrinks like any failure), an
    address-space cap as a safety net; and nothing added to or removed from the ``watch`` folders."""
    before = {p: listing(p) for p in watch}
    start = _status_kb("VmRSS") / 1024
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _status_kb("VmSize") * 1024 + ADDRESS_HEADROOM
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    old = signal.signal(signal.SIGALRM, _on_alarm)
    _reset_peak()
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    signal.setitimer(signal.ITIMER_REAL, HARD_STOP_S)
    t0, cpu0 = time.monotonic(), time.process_time()
    try:
        yield
    except Overrun:
        raise AssertionError(f"the reading ran past {HARD_STOP_S} s and was stopped") from None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    cpu = time.process_time() - cpu0
    assert cpu <= MAX_CPU_S, (
        f"the reading took {cpu:.1f} s of CPU (at most {MAX_CPU_S:g}), {time.monotonic() - t0:.1f} s"
    )
    peak = peak_rss_mb()
    assert peak - start <= MAX_ADDED_MB, (
        f"peak RSS {peak:.0f} MB during the reading, {peak - start:.0f} MB over its start (at most {MAX_ADDED_MB}), "
        f"{time.monotonic() - t0:.1f} s"
    )
    for p in watch:
        after = listing(p)
        assert after == before[p], (
            f"the reading changed {p}: added {sorted(after - before[p])[:5]}, removed {sorted(before[p] - after)[:5]}"
        )


class Refused:
    """What a door raised when it refused its input (one of the accepted error types)."""

    def __init__(self, error: BaseException):
        self.error = error

    def __repr__(self) -> str:
        return f"Refused({self.error!r})"


def door(call, accept: tuple[type[BaseException], ...], watch: tuple[Path, ...] = ()):
    """``call()`` within :func:`bounded`: its value, or :class:`Refused` when it raised one of
    ``accept`` (one line of text, no control characters: the command prints it as one ERROR line);
    any other exception propagates (a hole)."""
    with bounded(watch):
        try:
            value = call()
        except accept as e:
            value = Refused(e)
    if isinstance(value, Refused):
        text = str(value.error)
        bad = next((c for c in text if unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp")), None)
        assert bad is None, f"the error message holds the character {bad!r}: not one clean ERROR line: {text[:300]!r}"
    return value


# ----------------------------------------------------------------------------- hostile values


class Raw:
    """Text put verbatim into a JSON document (:func:`dumps`): numbers Python cannot write
    (5,000 digits, 1e400), nesting deeper than ``json.dumps`` recurses, NaN tokens."""

    def __init__(self, text: str):
        self.text = text

    def __repr__(self) -> str:
        return f"Raw({self.text[:60]!r}{'...' if len(self.text) > 60 else ''} [{len(self.text)} chars])"

    def __eq__(self, other) -> bool:
        return isinstance(other, Raw) and other.text == self.text

    def __hash__(self) -> int:
        return hash(self.text)


class Shown:
    """A drawn value shown short (Hypothesis prints what a failing test drew; a list nested 5,000
    deep or of 200,000 items would print for minutes, or overflow the printer's recursion)."""

    def __init__(self, value: Any):
        self.value = value

    def __repr__(self) -> str:
        import reprlib

        r = reprlib.Repr()
        r.maxlevel, r.maxstring, r.maxother, r.maxlist, r.maxdict = 4, 80, 80, 8, 12
        return f"Shown({r.repr(self.value)})"

    def _repr_pretty_(self, p, cycle) -> None:
        p.text(repr(self))


def nested(n: int, leaf: str = "1") -> Raw:
    return Raw("[" * n + leaf + "]" * n)


#: numbers that broke a door once, or sit at a bound's edge
EDGE_NUMBERS = [
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    5e-324,
    -0.0,
    1e300,
    1e23,
    1e6 + 1,
    2**53 + 1,
    2**63,
    -(2**63) - 1,
    10**30,
    10**31,
    20001,
    301,
    -5,
    99999,
]
NUMBERS = st.one_of(
    st.sampled_from(EDGE_NUMBERS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.integers(min_value=31, max_value=6000).map(lambda n: Raw("9" * n)),
    st.sampled_from([Raw("1e400"), Raw("-1e400"), Raw("NaN"), Raw("Infinity"), Raw("-Infinity"), Raw("1" * 4301)]),
)
#: text that is a number to float() but not in JSON, a formula, a terminal escape, a path
EDGE_TEXTS = [
    "1234",
    "1e308",
    "nan",
    "inf",
    "",
    "abc",
    "0x10",
    "1_000",
    "\uff11\uff12",
    "\u0663",
    '=HYPERLINK("http://x","y")',
    "+cmd|' /C calc'!A0",
    "-2-3",
    "-A1-B1",
    "\x1b]0;pwned\x07",
    "\x1b[2J",
    "a\u0085b",
    "photo\u202egpj.exe",
    "../../x",
    "/etc/passwd",
    "a/b",
    "a\\b",
    "..",
    "\x00",
    "\ud800",
    "x" * 10_000,
]
TEXTS = st.one_of(st.sampled_from(EDGE_TEXTS), st.text(max_size=30))
CONTAINERS = st.one_of(
    st.builds(list),  # a new one each time: a later mutation must not change what the strategy draws
    st.builds(dict),
    st.lists(st.one_of(NUMBERS, TEXTS), max_size=4),
    st.dictionaries(TEXTS, NUMBERS, max_size=3),
    st.sampled_from([31, 32, 33, 100, 5000, 100_000]).map(nested),
    st.sampled_from([40, 2000]).map(lambda n: Raw('{"a": ' * n + "1" + "}" * n)),
    st.integers(min_value=1000, max_value=200_000).map(lambda n: Raw("[" + ",".join(["1"] * n) + "]")),
)
HOSTILE = st.one_of(NUMBERS, TEXTS, CONTAINERS, st.booleans(), st.none())


# ----------------------------------------------------------------------------- JSON


def dumps(doc: Any) -> str:
    """``doc`` as JSON text, NaN and inf written as Python writes them, :class:`Raw` verbatim."""
    raws: list[str] = []

    def default(o):
        if isinstance(o, Raw):
            raws.append(o.text)
            return f"\x00raw{len(raws) - 1}\x00"
        raise TypeError(type(o).__name__)

    text = json.dumps(doc, default=default, allow_nan=True)
    for i, r in enumerate(raws):
        text = text.replace(json.dumps(f"\x00raw{i}\x00"), r, 1)
    return text


def loads_plain(text: str | bytes) -> Any:
    """``text`` parsed as Python does (long integers as floats, NaN as NaN), or None when it is no JSON:
    what an oracle compares a door's value with."""
    try:
        return json.loads(text, parse_int=lambda s: int(s) if len(s) <= 4000 else float(s))
    except (ValueError, RecursionError, TypeError):
        return None


def nodes(doc: Any, limit: int = 3000) -> list[tuple]:
    """The paths (tuples of keys and indices) of every value in ``doc``, the root first."""
    out, stack = [()], [((), doc)]
    while stack and len(out) < limit:
        p, v = stack.pop()
        children = list(v.items()) if isinstance(v, dict) else list(enumerate(v)) if isinstance(v, list) else []
        for k, c in children:
            out.append((*p, k))
            stack.append(((*p, k), c))
    return out


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


def _set(doc, path, value):
    if not path:
        return value
    _get(doc, path[:-1])[path[-1]] = value
    return doc


def _delete(doc, path):
    if path:
        parent = _get(doc, path[:-1])
        del parent[path[-1]]
    return doc


JSON_OPS = ("replace", "replace", "replace", "delete", "as_text", "wrap", "scale", "repeat", "add_key")


@st.composite
def mutated_json(draw, doc: Any, max_mutations: int = 3, keys: tuple[str, ...] = ()) -> Any:
    """``doc`` (a parsed JSON value, kept as is) with up to ``max_mutations`` changes: a value
    replaced by a hostile one, a key deleted, a number written as text, a value wrapped in a list,
    scaled to 1e300, a list repeated thousands of times, a key added (``keys``: known key names)."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(min_value=0, max_value=max_mutations))):
        paths = nodes(doc)
        path = draw(st.sampled_from(paths))
        value = _get(doc, path)
        op = draw(st.sampled_from(JSON_OPS))
        if op == "replace":
            doc = _set(doc, path, draw(HOSTILE))
        elif op == "delete" and path:
            doc = _delete(doc, path)
        elif op == "as_text":
            doc = _set(doc, path, value if isinstance(value, str) else dumps(value))
        elif op == "wrap":
            doc = _set(doc, path, draw(st.sampled_from([[value], {"value": value}, [value, value]])))
        elif op == "scale" and isinstance(value, (int, float)) and not isinstance(value, bool):
            factor = draw(st.sampled_from([1e300, -1e300, 1e6, -1.0, 0.0, 1e-300, math.inf, math.nan]))
            doc = _set(doc, path, value * factor if not math.isnan(factor) else factor)
        elif op == "repeat" and isinstance(value, list) and value:
            times = draw(st.sampled_from([2, 3, 101, 301, 1001, 20_001]))
            doc = _set(doc, path, (value * (times // len(value) + 1))[:times])
        elif op == "add_key" and isinstance(value, dict):
            key = draw(st.one_of(st.sampled_from(keys), TEXTS) if keys else TEXTS)
            value[key] = draw(HOSTILE)
    return doc


class Blob(bytes):
    """A file's bytes, shown by their size and start (Hypothesis prints what a failing test drew)."""

    def __repr__(self) -> str:
        return f"<{len(self):,} bytes: {bytes(self[:80])!r}{'...' if len(self) > 80 else ''}>"

    def _repr_pretty_(self, p, cycle) -> None:  # Hypothesis' printer: the short form too
        p.text(repr(self))


#: a file's bytes are kept as written in 3 examples of 5, else changed one of these ways
BYTE_OPS = ("truncate", "flip", "insert", "bom", "utf16", "empty", "nest", "garbage", "nul")


def corrupted(data: bytes):
    """:func:`_corrupted`, its bytes shown short (:class:`Blob`)."""
    return _corrupted(data).map(Blob)


@st.composite
def _corrupted(draw, data: bytes) -> bytes:
    """``data`` with at most one byte-level change: cut, a byte flipped, invalid UTF-8 or a control
    inserted, a BOM or UTF-16, emptied, wrapped in deep brackets, replaced by garbage."""
    if draw(st.integers(min_value=0, max_value=4)) < 3:
        return data
    op = draw(st.sampled_from(BYTE_OPS))
    n = len(data)
    at = draw(st.integers(min_value=0, max_value=max(n - 1, 0)))
    if op == "truncate":
        return data[:at]
    if op == "flip" and n:
        return data[:at] + bytes([data[at] ^ draw(st.integers(min_value=1, max_value=255))]) + data[at + 1 :]
    if op == "insert":
        return (
            data[:at] + draw(st.sampled_from([b"\xff\xfe", b"\xc3", b"\x1b[2J", b"\x00", b"\xed\xa0\x80"])) + data[at:]
        )
    if op == "bom":
        return b"\xef\xbb\xbf" + data
    if op == "utf16":
        return data.decode("utf-8", "replace").encode("utf-16")
    if op == "empty":
        return b""
    if op == "nest":
        k = draw(st.sampled_from([33, 1000, 100_000]))
        return b"[" * k + data + b"]" * k
    if op == "garbage":
        return draw(st.binary(max_size=64))
    if op == "nul":
        return data + b"\x00"
    return data


# ----------------------------------------------------------------------------- files

#: what a path handed to a reader can be (:func:`file_kind`: a regular file in 2 examples of 3)
FILE_KINDS = (
    "file",
    "link",
    "fifo",
    "folder",
    "link_to_fifo",
    "dangling_link",
    "link_loop",
    "link_to_dev_zero",
    "link_to_dev_null",
    "sparse_over_bound",
    "empty",
)


@st.composite
def file_kind(draw) -> str:
    """What a path is (:data:`FILE_KINDS`): a regular file in 2 examples of 3 (and what it shrinks to)."""
    return "file" if draw(st.integers(min_value=0, max_value=2)) < 2 else draw(st.sampled_from(FILE_KINDS))


def place(folder: Path, name: str, data: bytes, kind: str = "file", bound: int = 0) -> Path:
    """``folder/name`` made as ``kind`` (:data:`FILE_KINDS`) holding ``data`` where it holds anything;
    ``sparse_over_bound``: ``data`` then holes up to one byte past ``bound`` (nothing written)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    real = folder / f"real-{name}"
    if kind in ("file", "empty"):
        path.write_bytes(data if kind == "file" else b"")
    elif kind == "link":
        real.write_bytes(data)
        path.symlink_to(real.name)
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
        (path / "inner.json").write_bytes(data)
    elif kind == "link_to_fifo":
        os.mkfifo(real)
        path.symlink_to(real.name)
    elif kind == "dangling_link":
        path.symlink_to("no-such-file")
    elif kind == "link_loop":
        path.symlink_to(path.name)
    elif kind == "link_to_dev_zero":
        path.symlink_to("/dev/zero")
    elif kind == "link_to_dev_null":
        path.symlink_to("/dev/null")
    elif kind == "sparse_over_bound":
        with open(path, "wb") as f:
            f.write(data)
            f.truncate(max(bound + 1, len(data)))
    else:
        raise ValueError(kind)
    return path


# ----------------------------------------------------------------------------- zip members


def rezip(src: Path, dst: Path, deflate: bool = True, lie: int | None = None) -> Path:
    """The zip archive ``src`` (a torch checkpoint, a ``.npz``) written again as ``dst``, its members
    deflated; ``lie``: the first member's uncompressed size in the central directory replaced by it
    (a size that does not tell what the member inflates to)."""
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w") as out:
        for info in z.infolist():
            zi = zipfile.ZipInfo(info.filename, info.date_time)
            zi.compress_type = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
            out.writestr(zi, z.read(info))
    if lie is not None:
        data = bytearray(dst.read_bytes())
        at = data.find(b"PK\x01\x02")
        if at >= 0:
            data[at + 24 : at + 28] = int(lie % 2**32).to_bytes(4, "little")
        dst.write_bytes(bytes(data))
    return dst


def inflating_member(src: Path, dst: Path, member_end: str, inflated: int) -> Path:
    """``src`` (a zip) as ``dst`` whose member named ``...member_end`` is its bytes then zeros up to
    ``inflated`` bytes, deflated (a few hundred kB per gigabyte): a bomb that only the members'
    uncompressed sizes reveal. Written in chunks: building it holds 16 MB."""
    zero = bytes(1 << 24)
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w") as out:
        for info in z.infolist():
            data = z.read(info)
            zi = zipfile.ZipInfo(info.filename, info.date_time)
            zi.compress_type = zipfile.ZIP_DEFLATED
            if info.filename.endswith(member_end):
                with out.open(zi, "w", force_zip64=True) as f:
                    f.write(data)
                    for _ in range(inflated // len(zero)):
                        f.write(zero)
            else:
                out.writestr(zi, data)
    return dst


# ----------------------------------------------------------------------------- YAML


def alias_bomb(levels: int, width: int = 9) -> str:
    """A YAML "billion laughs": ``levels`` anchors each listing the previous ``width`` times
    (``width ** levels`` nodes once expanded, a few hundred bytes of text)."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, levels + 1):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- tables (Parquet, CSV)

#: the columns a map table's readers look for, and names a mutation may rename a column to
MAP_COLUMNS = (
    "lon",
    "lat",
    "longitude",
    "x_m",
    "y_m",
    "class",
    "class_label",
    "label",
    "class_id",
    "obj_idx",
    "geometry",
)
POSES_COLUMNS = (
    "scene",
    "token",
    "x_m",
    "y_m",
    "theta_deg",
    "lon",
    "lat",
    "heading_deg",
    "map_type",
    "proposal",
    "seconds",
)
#: values a cell of a number column may be given
CELL_NUMBERS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, 2.0**63, -(2.0**63), 1e6 + 1, 0.0, None]
CELL_INTS = [None, -1, 2**62, -(2**63), 10**18, 0, 20_001]
#: a Parquet writer's options: compression, dictionary encoding, row groups, page format
PARQUET_OPTIONS = st.fixed_dictionaries(
    {
        "compression": st.sampled_from(["snappy", "none", "zstd", "gzip", "brotli", "lz4"]),
        "use_dictionary": st.booleans(),
        "row_group_size": st.sampled_from([None, 1, 7]),
        "data_page_version": st.sampled_from(["1.0", "2.0"]),
        "store_schema": st.booleans(),
    }
)


def _surrogate(text: str) -> bool:
    """Whether ``text`` holds a lone surrogate (no Parquet or CSV file can hold one: not UTF-8)."""
    return any(0xD800 <= ord(c) <= 0xDFFF for c in text)


def _column_values(draw, col, n: int) -> list:
    """A column's values with one or a few cells hostile (of the column's kind where it can be)."""
    import pyarrow as pa

    values = col.to_pylist()
    if not n:
        return values
    kind = col.type
    pool = (
        CELL_NUMBERS
        if pa.types.is_floating(kind)
        else CELL_INTS
        if pa.types.is_integer(kind)
        else [t for t in EDGE_TEXTS if not _surrogate(t)] + [None]
        if pa.types.is_string(kind) or pa.types.is_large_string(kind)
        else [b"", b"\x01\x01\x00\x00\x00", b"garbage", None]
    )
    for _ in range(draw(st.integers(min_value=1, max_value=3))):
        values[draw(st.integers(min_value=0, max_value=n - 1))] = draw(st.sampled_from(pool))
    return values


RETYPES = ("text", "list", "bool", "dict", "null", "float")


def _retyped(col, to: str):
    """A column as another type (:data:`RETYPES`): text for numbers, one-item lists, booleans,
    dictionary-encoded, all nulls, floats for text."""
    import pyarrow as pa

    values = col.to_pylist()
    if to == "text":
        return pa.array([None if v is None else str(v) for v in values])
    if to == "list":
        return pa.array([[1] if isinstance(v, bytes) else [v] for v in values])
    if to == "bool":
        return pa.array([bool(v) for v in values])
    if to == "dict":
        return col if pa.types.is_dictionary(col.type) else col.dictionary_encode()
    if to == "null":
        return pa.nulls(len(values))
    return pa.array([float(len(str(v))) for v in values])


@st.composite
def mutated_table(draw, table, renames: tuple[str, ...], max_mutations: int = 3):
    """A pyarrow table with up to ``max_mutations`` changes: hostile cells (NaN, inf, 1e308, nulls,
    formulas), a column of another type (text for numbers, lists, booleans, dictionary-encoded), a
    column left out or renamed, rows taken again, cut or multiplied past a bound (301, 20,001),
    its ``flatlandia``/``geo`` metadata mutated or garbage; then, in one table of 8, a text cell
    that is no UTF-8."""
    import pyarrow as pa

    for _ in range(draw(st.integers(min_value=0, max_value=max_mutations))):
        if not table.column_names:
            break
        try:
            table = _table_op(draw, table, renames)
        except pa.ArrowException:  # an op pyarrow has no kernel for (a list column dictionary-encoded)
            continue
    text = [k for k, f in enumerate(table.schema) if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]
    if text and table.num_rows and draw(st.integers(min_value=0, max_value=7)) == 0:  # last: nothing reads it back
        k = draw(st.sampled_from(text))
        row = draw(st.integers(min_value=0, max_value=table.num_rows - 1))
        table = table.set_column(k, table.column_names[k], _invalid_utf8(table.column(k).combine_chunks(), row))
    return table


def _table_op(draw, table, renames: tuple[str, ...]):
    """One change of :func:`mutated_table`."""
    import pyarrow as pa

    names = table.column_names
    op = draw(st.sampled_from(["cell", "cell", "type", "drop", "rename", "rows", "grow", "meta", "meta"]))
    i = draw(st.integers(min_value=0, max_value=len(names) - 1))
    col, n = table.column(i).combine_chunks(), table.num_rows
    if op == "cell":
        values = _column_values(draw, col, n)
        try:
            new = pa.array(values, type=col.type)
        except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError, TypeError):
            new = pa.array([None if v is None else str(v) for v in values])
        return table.set_column(i, names[i], new)
    if op == "type":
        return table.set_column(i, names[i], _retyped(col, draw(st.sampled_from(RETYPES))))
    if op == "drop":
        return table.remove_column(i)
    if op == "rename":
        return table.rename_columns([draw(st.sampled_from(renames)) if k == i else c for k, c in enumerate(names)])
    if op == "rows":
        rows = draw(st.lists(st.integers(min_value=0, max_value=max(n - 1, 0)), max_size=n + 2)) if n else []
        return table.take(pa.array(rows, pa.int64()))
    if op == "grow" and n:
        size = draw(st.sampled_from([301, 2000, 20_001]))
        return table.take(pa.array([k % n for k in range(size)], pa.int64()))
    if op == "meta":
        return table.replace_schema_metadata(draw(_mutated_metadata(table.schema.metadata or {})))
    return table


def _invalid_utf8(col, row: int):
    """A text column whose ``row``-th value starts with the byte 0xFF (no UTF-8): made from its
    buffers, which pyarrow does not check, so the file holds what no writer of text would write."""
    import pyarrow as pa

    values = [v.encode() if isinstance(v, str) else b"" for v in col.to_pylist()]
    values[row] = b"\xff" + values[row][1:]
    large = pa.types.is_large_string(col.type)
    binary = pa.array(values, pa.large_binary() if large else pa.binary())
    return pa.Array.from_buffers(pa.large_string() if large else pa.string(), len(binary), binary.buffers())


@st.composite
def _mutated_metadata(draw, meta: dict) -> dict:
    meta = dict(meta)
    key = draw(st.sampled_from([b"flatlandia", b"flatlandia", b"geo", b"pandas"]))
    if key not in meta:
        return meta
    doc = loads_plain(meta[key])
    how = draw(st.sampled_from(["json", "json", "bytes", "drop"]))
    if how == "drop":
        del meta[key]
    elif how == "json" and doc is not None:
        meta[key] = dumps(draw(mutated_json(doc, keys=("lon0", "lat0", "frame", "scene", "crs")))).encode(
            "utf-8", "surrogatepass"
        )
    else:
        meta[key] = draw(corrupted(meta[key]))
    return meta


def write_parquet(table, path: Path, options: dict) -> None:
    """``table`` written with the writer ``options`` (:data:`PARQUET_OPTIONS`); a combination pyarrow
    refuses is written with its defaults, a table it cannot write (nulls in a dictionary) with its
    dictionary columns decoded; a table pyarrow cannot write at all is no example (rejected)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from hypothesis import reject

    for attempt in (lambda: pq.write_table(table, path, **options), lambda: pq.write_table(table, path)):
        try:
            return attempt()
        except (pa.ArrowException, ValueError, TypeError):
            continue
    try:
        plain = [c.cast(c.type.value_type) if pa.types.is_dictionary(c.type) else c for c in table.columns]
        pq.write_table(pa.table(plain, names=table.column_names, metadata=table.schema.metadata), path)
    except (pa.ArrowException, ValueError, TypeError):
        reject()


def dictionary_bomb(table, path: Path, rows: int, value_bytes: int) -> Path:
    """``table``'s rows taken again up to ``rows``, with a column of one text of ``value_bytes``
    bytes, dictionary-encoded (the file: the text once) and stored without the Arrow schema, so a
    reader decodes it in full: ``rows * value_bytes`` bytes from a file of a few tens of kB (the
    footer's sizes count the encoded bytes)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    big = table.take(pa.array([k % table.num_rows for k in range(rows)], pa.int64()))
    pad = pa.DictionaryArray.from_arrays(pa.array([0] * rows, pa.int32()), pa.array(["x" * value_bytes]))
    pq.write_table(big.append_column("pad", pad), path, dictionary_pagesize_limit=10**9, store_schema=False)
    return path


CSV_CELLS = EDGE_TEXTS[:14] + [" 1", "1.5e", "-0", "9" * 400, "1e-400", "0" * 50 + "1", "\t1", "'=1"]


@st.composite
def mutated_csv(draw, df, max_mutations: int = 3) -> str:
    """``df`` as CSV text with up to ``max_mutations`` changes: a cell hostile (NaN, 1e308,
    ``1_000``, full-width digits, formulas, controls, 400 digits), a column left out, renamed or
    added (a setting column of hostile values), rows taken again or multiplied, the header cut."""
    t = df.astype(str)
    for _ in range(draw(st.integers(min_value=0, max_value=max_mutations))):
        op = draw(st.sampled_from(["cell", "cell", "cell", "drop", "rename", "add", "rows", "grow"]))
        cols = list(t.columns)
        if op == "cell" and len(t) and cols:
            t.iat[draw(st.integers(0, len(t) - 1)), draw(st.integers(0, len(cols) - 1))] = draw(
                st.one_of(st.sampled_from(CSV_CELLS), st.text(max_size=8))
            )
        elif op == "drop" and cols:
            t = t.drop(columns=draw(st.sampled_from(cols)))
        elif op == "rename" and cols:
            old = draw(st.sampled_from(cols))
            t = t.rename(columns={old: draw(st.sampled_from(POSES_COLUMNS + ("", " x_m", "X_M")))})
        elif op == "add":
            t[draw(st.sampled_from(["map_type", "proposal", "seconds", "lon", "extra"]))] = draw(
                st.sampled_from(["depth", "gt", "whole", "rgb", "-1", "nan", "1e308", "", "0.5"])
            )
        elif op == "rows" and len(t):
            t = t.iloc[draw(st.lists(st.integers(0, len(t) - 1), max_size=len(t) + 2))]
        elif op == "grow" and len(t):
            t = t.iloc[[k % len(t) for k in range(draw(st.sampled_from([301, 20_000])))]]
    return t.to_csv(index=False)


def compress(data: bytes, suffix: str) -> bytes:
    """``data`` compressed as its ``suffix`` says (``.gz``, ``.bz2``, ``.xz``; else as it is)."""
    import bz2
    import gzip
    import lzma

    if suffix.endswith(".gz"):
        return gzip.compress(data, compresslevel=1)
    if suffix.endswith(".bz2"):
        return bz2.compress(data, 1)
    if suffix.endswith(".xz"):
        return lzma.compress(data, preset=0)
    return data
