"""Checks at the doors: what a file read from outside a run must be before any code uses it.

Why one module: the files a user or a download controls (a query or sequence JSON, a map Parquet
or GeoJSON, a city index ``.npz``, a priors JSON, a poses CSV or Parquet, a provenance record)
reach numba kernels, pyproj and torch, which do not check what they are given: a pointer out of
range is a segfault, a NaN a silently wrong pose, a size nobody bounded an hour of CPU or all the
memory. Every reader calls the checks here before the data is used, and each failed check is one
:class:`~flatlandia.plumbing.errors.InputError` naming the file and the problem.

The bounds are named constants, all of them here (docs/security.md says why each has its value and
what its worst input cost, measured). Each is far above what the benchmark's own files need (noted
beside it).
"""

from __future__ import annotations

import functools
import json
import math
import os
import stat
from collections.abc import Hashable
from pathlib import Path
from typing import Any

import numpy as np

from flatlandia.plumbing.errors import InputError

MB = 1_000_000

# ----------------------------------------------------------------------------- bounds

#: any JSON file the workflow reads (the published local_maps.json: 1.1 MB)
MAX_JSON_BYTES = 64 * MB
#: a query or sequence file of ``flatlandia localize`` (a query of 17 objects: under 2 kB)
MAX_QUERY_JSON_BYTES = 8 * MB
#: nesting of any JSON value (a query file needs 4 levels, a provenance record 4, a checkpoint's config 3)
MAX_JSON_DEPTH = 32
#: nesting of a config value (the schema's deepest key: 4 levels; Snakemake's own YAML loader
#: fails on its own far deeper: docs/security.md, "The bounds")
MAX_CONFIG_DEPTH = 16
#: a config file given to a run (config/config.yaml: 27 kB)
MAX_CONFIG_BYTES = 1 * MB
#: values of a config once its YAML aliases are expanded, keys counted (config/config.yaml: 525); a
#: 477-byte alias bomb holds 9**9 and took 14 min of CPU before any message
MAX_CONFIG_NODES = 100_000
#: digits of a JSON integer read as an integer (longer ones are read as floats, so 10**400 is inf)
MAX_INT_DIGITS = 30
#: objects of one query (the published local maps hold at most 17; far more ran for minutes:
#: docs/security.md, "The bounds")
MAX_QUERY_OBJECTS = 100
#: queries of one query file (the benchmark's test split: 215)
MAX_QUERIES = 10_000
#: frames of one sequence (the benchmark's sequences: 5; the cost grows with the frames: docs/security.md, "The bounds")
MAX_SEQUENCE_FRAMES = 20
#: largest coordinate of a query's local map, any unit (metres of a GT map: a camera sees 100 m)
MAX_LOCAL_COORD = 1e6
#: largest odometry step of a sequence frame from the anchor, metres (a scene is under 1 km across)
MAX_ODOMETRY_M = 10_000.0
#: largest GPS sigma or search radius, metres (a phone's fix: 3-50 m; a city: 20 km)
MAX_PRIOR_M = 1_000_000.0
#: largest compass sigma, degrees (beyond half a turn a compass says nothing)
MAX_COMPASS_SIGMA_DEG = 180.0
#: objects of a scene map file (a scene: about 120; the solver's time grows with the map,
#: docs/security.md, "The bounds": a larger map is a city, searched through its index)
MAX_MAP_OBJECTS = 20_000
#: objects of one class in a scene map (a published scene: at most 86): the solver's candidates, and
#: its time, grow with it (docs/security.md, "The bounds")
MAX_CLASS_OBJECTS = 300
#: objects of a city index (the simulated city: 100,000)
MAX_INDEX_OBJECTS = 1_000_000
#: a map file on disk (Parquet, GeoJSON; a scene's: 10-60 kB)
MAX_MAP_BYTES = 256 * MB
#: a city index: the ``.npz`` on disk and its arrays once unpacked (the 20-scene city's: 0.2 MB)
MAX_INDEX_BYTES = 256 * MB
#: members of a city index's ``.npz`` (it holds 7 arrays)
MAX_INDEX_MEMBERS = 1000
#: a poses file, on disk and (a compressed CSV) once decompressed (215 test queries x 12 settings: 0.3 MB)
MAX_POSES_BYTES = 64 * MB
#: rows of a poses file (every query of 20 scenes in 12 settings: 26,000)
MAX_POSES_ROWS = 200_000
#: a CSV of an export read back (``localize --batch``; the export's largest, proposals.csv: 12 MB for
#: every scene, a scene's under 2 MB)
MAX_CSV_BYTES = 64 * MB
#: a checkpoint file, on disk and its members once inflated (the default run's largest: 0.6 MB; the
#: paper's GAT: 3 MB)
MAX_CHECKPOINT_BYTES = 256 * MB
#: members of a checkpoint's zip (torch.save writes 3 and one per tensor: the paper's GAT, about 60)
MAX_CHECKPOINT_MEMBERS = 10_000
#: a Parquet file's footer, parsed before any column (a scene map's: 11 kB; a poses file's: 4 kB)
MAX_PARQUET_FOOTER_BYTES = 4 * MB
#: columns of a Parquet file read from outside (a scene map: 9; a poses file: 5-8)
MAX_PARQUET_COLUMNS = 1000
#: row groups of any Parquet (the workflow writes one per file; pyarrow's default holds 1M rows): each
#: costs a pass of the page-header check, and 2,000 one-row groups took 3 s (the fuzz suite's find)
MAX_PARQUET_ROW_GROUPS = 1000
#: pages of a Parquet file read from outside, each header read before pyarrow reads it (a scene
#: map's: 20; pyarrow writes a page per MB of a column)
MAX_PARQUET_PAGES = 100_000
#: bytes of all the page headers of a Parquet file together, each read before pyarrow reads it
#: (a header: 20-60 bytes; a scene map's all: under 2 kB)
MAX_PARQUET_HEADER_BYTES = 4 * MB
#: a provenance record (the default run's largest: 40 kB)
MAX_RECORD_BYTES = 16 * MB
#: a map's lon0/lat0 (its metric frame's origin) may lie this far from its objects' centre, metres
MAX_ORIGIN_OFFSET_M = 50_000.0
#: a map's x_m/y_m must be its lon/lat projected in its own frame to within this, metres
FRAME_TOLERANCE_M = 1.0
#: characters of a value quoted in an error message (a 100 MB token is shown by its start)
SHOW_CHARS = 80


# ----------------------------------------------------------------------------- messages


def shown(value: Any, limit: int = SHOW_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (with how long it was): an error line quotes
    what it refuses without echoing a 100 MB value."""
    if isinstance(value, str) and len(value) > 4 * limit:
        value = value[: 4 * limit]  # repr of a huge string is never built
        text = repr(value)[:limit]
        return f"{text}... (a text longer than {4 * limit} characters)"
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


# ----------------------------------------------------------------------------- files


def regular_file(path: str | Path, max_bytes: int | None = None, limit_name: str = "") -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a regular file of at most ``max_bytes``; a folder,
    a named pipe, a device or a socket is refused without being opened (a FIFO would block the
    reader, ``/dev/zero`` never ends), and so is a file over the bound (``limit_name`` names it)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(path, "file is missing") from None
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(path, "is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(path, "is not a regular file (a named pipe, a device or a socket): refused without reading it")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputError(path, f"{st.st_size:,} bytes, over the limit of {max_bytes:,}{_named(limit_name)}")
    return st


def one_line(error: BaseException | str, limit: int = 300) -> str:
    """A library's error message as one line of at most ``limit`` characters (pyarrow's and
    geopandas' messages span lines; an ERROR line is one)."""
    text = " ".join(str(error).split())
    return text if len(text) <= limit else f"{text[:limit]}..."


def _named(limit_name: str) -> str:
    return f" (flatlandia.plumbing.validate.{limit_name})" if limit_name else ""


def read_bytes(path: str | Path, max_bytes: int, limit_name: str = "") -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (:func:`regular_file`), read without
    ever holding more than that: a file that grows while it is read, or was swapped for a pipe
    after the check, is refused too (opened non-blocking, checked again on the open file)."""
    regular_file(path, max_bytes, limit_name)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or e})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputError(path, "is not a regular file: refused without reading it")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputError(path, f"over the limit of {max_bytes:,} bytes{_named(limit_name)}")
    return data


def read_decompressed(path: str | Path, opener, max_bytes: int, limit_name: str = "") -> bytes:
    """The decompressed bytes of a compressed regular file (``opener``: gzip.open, bz2.open,
    lzma.open), streamed and stopped as soon as they pass ``max_bytes``: a 4 MB archive of 2 GB
    is refused after reading ``max_bytes``, never holding more."""
    regular_file(path, max_bytes, limit_name)
    out, n = [], 0
    try:
        with opener(path, "rb") as f:
            while chunk := f.read(1 << 20):
                n += len(chunk)
                if n > max_bytes:
                    raise InputError(
                        path, f"decompresses to over {max_bytes:,} bytes, over the limit{_named(limit_name)}"
                    )
                out.append(chunk)
    except InputError:
        raise
    except (OSError, EOFError, ValueError) as e:  # gzip.BadGzipFile, lzma.LZMAError, ...
        raise InputError(path, f"not a readable compressed file ({type(e).__name__}: {e})") from None
    return b"".join(out)


def parquet_size(
    path: str | Path, max_rows: int, max_bytes: int, what: str = "rows", names: tuple[str, str] = ("", "")
) -> int:
    """Before a Parquet file is read: a regular file of at most ``max_bytes`` whose footer declares
    at most ``max_rows`` rows and at most ``max_bytes`` once uncompressed (its row groups' sizes);
    its number of rows. A file that is not Parquet raises pyarrow's error (each caller words it)."""
    import pyarrow.parquet as pq

    regular_file(path, max_bytes, names[1])
    _parquet_footer(path)
    meta = pq.ParquetFile(path).metadata  # a file that is not Parquet: pyarrow's error, the caller's message
    count(meta.num_rows, max_rows, path, what, names[0] or "a bound")
    count(meta.num_row_groups, MAX_PARQUET_ROW_GROUPS, path, "row groups", "MAX_PARQUET_ROW_GROUPS")
    count(
        sum(meta.row_group(i).num_rows for i in range(meta.num_row_groups)), max_rows, path, what, names[0] or "a bound"
    )
    raw = sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))
    if raw > max_bytes:
        raise InputError(
            path, f"its columns unpack to {raw:,} bytes, over the limit of {max_bytes:,}{_named(names[1])}"
        )
    return meta.num_rows


def _parquet_footer(path: str | Path) -> None:
    """A Parquet file's footer (its last 8 bytes: the footer's length, then ``PAR1``) is at most
    :data:`MAX_PARQUET_FOOTER_BYTES`, read before pyarrow parses it (a 60 MB footer of row groups
    would unpack to gigabytes of metadata). A file that is not Parquet is left to pyarrow's error."""
    with open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(max(size - 8, 0))
        tail = f.read(8)
    if len(tail) < 8 or tail[4:] != b"PAR1":
        return
    footer = int.from_bytes(tail[:4], "little")
    if footer > MAX_PARQUET_FOOTER_BYTES:
        raise InputError(
            path,
            f"its footer holds {footer:,} bytes, over the limit of {MAX_PARQUET_FOOTER_BYTES:,} (MAX_PARQUET_FOOTER_BYTES)",
        )


def _fixed_bytes(dtype) -> int | None:
    """Bytes per value of a fixed-width Arrow type (a bool: 1), None for one of variable width or a
    dictionary (pandas' categorical: its values, not its 4-byte indices, are what a cast decodes)."""
    import pyarrow as pa

    if pa.types.is_dictionary(dtype):
        return None
    try:
        return max(1, dtype.bit_width // 8)
    except ValueError:
        return None


def _decoded_bytes(column) -> int:
    """Bytes a dictionary-encoded column holds once decoded: each row's value length, taken from
    its dictionary, plus an 8-byte offset per row (computed on the indices: nothing is decoded)."""
    import pyarrow.compute as pc

    width = _fixed_bytes(column.type.value_type)
    if width is not None:  # a dictionary of numbers (pandas' categorical of integers)
        return width * len(column)
    total = 8 * len(column)
    for chunk in column.chunks:
        lengths = pc.binary_length(chunk.dictionary) if len(chunk.dictionary) else None
        if lengths is not None and len(chunk):
            total += int(pc.sum(pc.take(lengths, chunk.indices)).as_py() or 0)
    return total


def _varint(buf, pos: int, end: int) -> tuple[int, int]:
    """A Thrift compact-protocol varint (at most 10 bytes, before ``end``) and where it ends."""
    n = shift = 0
    for i in range(pos, min(pos + 10, end)):
        n |= (buf[i] & 0x7F) << shift
        shift += 7
        if not buf[i] & 0x80:
            return n, i + 1
    raise ValueError("a varint past its bound")


def _zigzag(buf, pos: int, end: int) -> tuple[int, int]:
    n, pos = _varint(buf, pos, end)
    return (n >> 1) ^ -(n & 1), pos


def _thrift_value(buf, pos: int, end: int, kind: int, depth: int):
    """One Thrift compact-protocol value of type ``kind`` at ``pos``, all of it before ``end``: (its
    value, where it ends); integers, structs and lists are read, other values skipped (None). A count is refused
    when its elements could not fit before ``end`` (each takes a byte at least): a hostile header
    costs at most a step per byte."""
    if depth > 16:
        raise ValueError("Thrift structures nested over 16 deep")
    if kind in (1, 2):  # a struct field's boolean sits in its type
        return kind == 1, pos
    if kind == 3:
        return buf[pos], pos + 1
    if kind in (4, 5, 6):
        return _zigzag(buf, pos, end)
    if kind in (7, 8):  # a double; a binary: its length, then its bytes
        n, pos = (8, pos) if kind == 7 else _varint(buf, pos, end)
        if pos + n > end:
            raise ValueError("a value past its bound")
        return None, pos + n
    if kind in (9, 10, 11):  # list, set: size and element type in one byte; map: size, then both types
        if kind == 11:
            n, pos = _varint(buf, pos, end)
            types, pos = (buf[pos] if n else 0), pos + (1 if n else 0)
            kinds, n = [types >> 4, types & 0x0F], 2 * n
        else:
            head, pos = buf[pos], pos + 1
            n, kinds = head >> 4, [head & 0x0F]
            if n == 15:
                n, pos = _varint(buf, pos, end)
        if n > end - pos:
            raise ValueError("more elements than bytes")
        values = []  # each element takes a byte at least: a list holds at most the bytes it spans
        for k in range(n):
            elem = kinds[k % len(kinds)]
            if elem in (1, 2):
                value, pos = buf[pos] == 1, pos + 1
            else:
                value, pos = _thrift_value(buf, pos, end, elem, depth + 1)
            values.append(value)
        return values, pos
    if kind == 12:
        return _thrift_struct(buf, pos, end, depth + 1)
    raise ValueError(f"unknown Thrift type {kind}")


class _Struct(dict):
    """A Thrift struct read by :func:`_thrift_struct`: {field id: value}, and ``kinds``, each field's
    wire type (Thrift's generated readers skip a field whose type is not the one they expect)."""

    def __init__(self):
        super().__init__()
        self.kinds: dict[int, int] = {}

    def typed(self, field: int, kind: int):
        """The field's value when it came with wire type ``kind`` (else None: skipped, as Thrift does)."""
        return self.get(field) if self.kinds.get(field) == kind else None


#: Thrift compact wire types the footer check reads
_I32, _LIST, _STRUCT = 5, 9, 12


def _thrift_struct(buf, pos: int, end: int, depth: int = 0) -> tuple[dict, int]:
    """A Thrift compact-protocol struct at ``pos``, all of it before ``end``: {field id: value} (a
    :class:`_Struct`, its fields' wire types beside) and where it ends."""
    fields = _Struct()
    last = 0
    while True:
        if pos >= end:
            raise ValueError("a struct past its bound")
        head, pos = buf[pos], pos + 1
        if head == 0:
            return fields, pos
        if head >> 4:
            last += head >> 4
        else:
            last, pos = _zigzag(buf, pos, end)
        fields.kinds[last] = head & 0x0F
        fields[last], pos = _thrift_value(buf, pos, end, head & 0x0F, depth)


def _leaf_levels(schema: Any, path: str | Path) -> list[tuple[int, int]]:
    """(max definition level, max repetition level) of each leaf column of a footer's schema (its
    SchemaElements in pre-order: field 3 the repetition, 5 the number of children), walked without
    recursion."""
    if not isinstance(schema, list) or not schema or not isinstance(schema[0], _Struct):
        raise InputError(path, "its footer holds no schema")
    leaves: list[tuple[int, int]] = []
    stack = [[schema[0].typed(5, _I32) or 0, 0, 0]]  # [children left, definition level, repetition level]
    for element in schema[1:]:
        while stack and stack[-1][0] <= 0:
            stack.pop()
        if not stack or not isinstance(element, _Struct):
            raise InputError(path, "its footer's schema does not hold together")
        stack[-1][0] -= 1
        kind = element.typed(3, _I32) or 0  # of another wire type: skipped, so REQUIRED
        if kind not in (0, 1, 2):  # REQUIRED, OPTIONAL, REPEATED (pyarrow reads another as REQUIRED)
            raise InputError(path, f"its footer's schema names a repetition {shown(kind)} Parquet does not know")
        levels = (stack[-1][1] + (kind != 0), stack[-1][2] + (kind == 2))
        children = element.typed(5, _I32) or 0
        if not isinstance(children, int) or children < 0:
            raise InputError(path, "its footer's schema does not hold together")
        if children:
            stack.append([children, *levels])
        else:
            leaves.append(levels)
    return leaves


def _check_footer(path: str | Path) -> None:
    """The footer as Parquet's Thrift schema has it, read here before pyarrow's accessors: each
    column chunk's level histograms (ColumnMetaData's size statistics) sized as the schema says.
    Why: pyarrow 26 checks them in a constructor its Python binding calls without exception
    handling, so a histogram of the wrong size (the fuzz suite's find) aborted the process
    ("terminate called after throwing parquet::ParquetException")."""
    size = os.stat(path).st_size
    with open(path, "rb") as f:
        if size < 12:
            return
        f.seek(size - 8)
        tail = f.read(8)
        n = int.from_bytes(tail[:4], "little")
        if tail[4:] != b"PAR1" or n > size - 12 or n > MAX_PARQUET_FOOTER_BYTES:
            return  # pyarrow refuses such a file (parquet_size has checked the bound)
        f.seek(size - 8 - n)
        buf = f.read(n)
    try:
        meta, _ = _thrift_struct(buf, 0, len(buf))
    except (IndexError, ValueError):
        raise InputError(path, "its footer is not Parquet's metadata") from None
    leaves = _leaf_levels(meta.typed(2, _LIST), path)
    for i, group in enumerate(meta.typed(4, _LIST) or []):
        chunks = group.typed(1, _LIST) if isinstance(group, _Struct) else None
        if not isinstance(chunks, list) or len(chunks) != len(leaves):
            raise InputError(path, f"row group {i} does not hold one column chunk per column of its schema")
        for leaf, chunk in zip(leaves, chunks, strict=True):
            column = chunk.typed(3, _STRUCT) if isinstance(chunk, _Struct) else None
            stats = column.typed(16, _STRUCT) if isinstance(column, _Struct) else None
            if not isinstance(stats, _Struct):
                continue
            for field, level in ((3, leaf[0]), (2, leaf[1])):
                histogram = stats.typed(field, _LIST)
                if histogram is not None and (not isinstance(histogram, list) or len(histogram) not in (0, level + 1)):
                    raise InputError(path, f"row group {i}: a level histogram that does not fit its column's schema")


def _page_sizes(path: str | Path, meta, max_bytes: int, limit_name: str) -> list[dict]:
    """Per leaf column, what its pages declare (their headers, read here before pyarrow reads them:
    pyarrow allocates each page's declared uncompressed size and never checks it against the footer,
    so a 3 kB file whose footer says 1 kB decompressed a 100 MB page): ``pages`` (decompressed bytes
    of all its pages), ``dictionary`` (its largest dictionary page), ``values`` (values its data pages
    declare). Refused: all pages together over ``max_bytes``, over :data:`MAX_PARQUET_PAGES` pages,
    a page header that is not one, a column chunk outside the file."""
    import mmap

    out = [{"pages": 0, "dictionary": 0, "values": 0} for _ in range(meta.num_columns)]
    pages = total = 0
    headers = MAX_PARQUET_HEADER_BYTES  # what is left of the bound on all page headers together
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        for i in range(meta.num_row_groups):
            rg = meta.row_group(i)
            if rg.num_columns != meta.num_columns:
                raise InputError(path, f"row group {i} holds {rg.num_columns} columns, its schema {meta.num_columns}")
            for j in range(rg.num_columns):
                c = rg.column(j)
                pos = (
                    c.dictionary_page_offset
                    if c.has_dictionary_page and c.dictionary_page_offset
                    else c.data_page_offset
                )
                end = pos + c.total_compressed_size
                if pos < 0 or c.total_compressed_size < 0 or end > len(buf):
                    raise InputError(path, f"column {shown(c.path_in_schema)}: its pages lie outside the file")
                while pos < end:
                    try:
                        header, after = _thrift_struct(buf, pos, min(end, pos + headers))
                    except (IndexError, ValueError):
                        raise InputError(
                            path,
                            f"column {shown(c.path_in_schema)}: a page header that cannot be read, or past "
                            f"{MAX_PARQUET_HEADER_BYTES:,} bytes of page headers (MAX_PARQUET_HEADER_BYTES)",
                        ) from None
                    headers, pos = headers - (after - pos), after
                    size, packed = header.get(2), header.get(3)
                    if not isinstance(size, int) or not isinstance(packed, int) or size < 0 or packed < 0:
                        raise InputError(path, f"column {shown(c.path_in_schema)}: a page header without its sizes")
                    pos += packed
                    pages, total = pages + 1, total + size
                    count(pages, MAX_PARQUET_PAGES, path, "pages", "MAX_PARQUET_PAGES")
                    _within(total, max_bytes, path, limit_name, "its pages decompress to")
                    leaf = out[j]
                    leaf["pages"] += size
                    if header.get(1) == 2:  # a dictionary page
                        leaf["dictionary"] = max(leaf["dictionary"], size)
                    for sub in (5, 8):  # data page v1, v2: field 1 is num_values
                        if isinstance(header.get(sub), dict):
                            leaf["values"] += max(0, int(header[sub].get(1) or 0))
    return out


def _leaves(fields, parquet_schema) -> dict[str, list[int]]:
    """The leaf columns (their indices in the file) of each top-level field, in schema order."""
    out, j = {}, 0
    paths = [parquet_schema.column(k).path for k in range(len(parquet_schema))]
    for field in fields:
        out[field.name] = []
        while j < len(paths) and (paths[j] == field.name or paths[j].startswith(field.name + ".")):
            out[field.name].append(j)
            j += 1
    return out


#: bytes per value of Parquet's fixed-width physical types (BYTE_ARRAY is of variable width; a
#: FIXED_LEN_BYTE_ARRAY's width is its schema's type_length)
_PHYSICAL_WIDTH = {"BOOLEAN": 1, "INT32": 4, "INT64": 8, "INT96": 12, "FLOAT": 4, "DOUBLE": 8}


def _leaf_widths(schema) -> list[int | None]:
    """Bytes per value of each leaf column (a ParquetSchema), None for a BYTE_ARRAY one."""
    out: list[int | None] = []
    for j in range(len(schema)):
        column = schema.column(j)
        kind = column.physical_type
        out.append(column.length if kind == "FIXED_LEN_BYTE_ARRAY" else _PHYSICAL_WIDTH.get(kind))
    return out


def _planned_bytes(field, leaves: list[int], sizes: list[dict], rows: int, widths: list | None = None) -> int:
    """An upper bound on what ``field`` decodes to, from its pages' headers: a flat fixed-width
    column rows x width; a flat text column its 4-byte indices and its pages (its dictionary;
    decoded later only once measured, :func:`_decoded_bytes`); a list or struct, each leaf value
    declared by its pages at its width (a text leaf: at its largest dictionary page) and an 8-byte
    offset. A fixed-width leaf (``widths``, :func:`_leaf_widths`) decodes to its width per value,
    whatever its dictionary (pyarrow dictionary-encodes doubles too)."""
    import pyarrow as pa

    width = _fixed_bytes(field.type)
    if not pa.types.is_nested(field.type):
        return rows * width if width else 4 * rows + sum(sizes[j]["pages"] for j in leaves)
    total = 0
    for j in leaves:
        leaf = sizes[j]
        fixed = widths[j] if widths is not None and j < len(widths) else None
        total += leaf["values"] * (8 + (fixed if fixed else max(8, leaf["dictionary"]))) + leaf["pages"]
    return total


def read_parquet(
    path: str | Path,
    max_rows: int,
    max_bytes: int,
    what: str = "rows",
    names: tuple[str, str] = ("", ""),
    columns: list[str] | None = None,
):
    """A Parquet table (pyarrow), read within bounds on what it DECODES to, not only on its footer's
    sizes, which count encoded bytes (a 5 kB file of 200,000 rows naming one 19 kB dictionary value
    unpacked to 3.8 GB): :func:`parquet_size` first; at most :data:`MAX_PARQUET_COLUMNS` columns;
    every page's header read before pyarrow reads it (:func:`_page_sizes`); an upper bound of what
    each column decodes to within ``max_bytes`` before reading (:func:`_planned_bytes`); flat text
    and binary columns read as dictionaries (what the file holds) and decoded only once their decoded
    size, computed from the dictionary's lengths, keeps the table within ``max_bytes``. Refusals are
    InputError (``names``: the row and byte bounds' names); a file that is not Parquet raises
    pyarrow's error (each caller words it)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = parquet_size(path, max_rows, max_bytes, what, names)
    _check_footer(path)
    file = pq.ParquetFile(path)
    count(file.metadata.num_columns, MAX_PARQUET_COLUMNS, path, "columns", "MAX_PARQUET_COLUMNS")
    schema = file.schema_arrow
    fields = list(schema)
    twice = sorted({f.name for f in fields if schema.get_all_field_indices(f.name)[1:]})
    if twice:
        raise InputError(path, f"column {shown(twice[0])} given twice: each column once")
    sizes = _page_sizes(path, file.metadata, max_bytes, names[1])
    leaves = _leaves(fields, file.schema)
    if columns is not None:
        fields = [schema.field(c) for c in columns]
    widths = _leaf_widths(file.schema)
    planned = sum(_planned_bytes(f, leaves.get(f.name, []), sizes, rows, widths) for f in fields)
    _within(planned, max_bytes, path, names[1], "its columns may decode to")
    text = [  # all-null columns (pyarrow's null type) hold nothing to decode
        f.name
        for f in fields
        if not pa.types.is_nested(f.type) and not pa.types.is_null(f.type) and _fixed_bytes(f.type) is None
    ]
    reader = pq.ParquetFile(path, read_dictionary=text)
    table = reader.read(columns=[f.name for f in fields], use_pandas_metadata=columns is None)
    decoded = planned - sum(_planned_bytes(schema.field(n), leaves.get(n, []), sizes, rows, widths) for n in text)
    for name in text:
        decoded += _decoded_bytes(table.column(name))
        _within(decoded, max_bytes, path, names[1], f"its columns (up to {shown(name)}) decode to")
    for name in text:
        want = schema.field(name).type
        if not pa.types.is_dictionary(want):  # a column written as a dictionary (pandas' categorical) stays one
            i = table.schema.get_field_index(name)
            table = table.set_column(i, schema.field(name), table.column(name).cast(want))
    try:  # every value as its type says (a text column's UTF-8): pandas trips on what pyarrow let by
        table.validate(full=True)
    except Exception as e:
        raise InputError(path, f"holds values that are not what its schema says ({one_line(e)})") from None
    return table


def read_table(
    path: str | Path,
    max_rows: int,
    max_bytes: int,
    names: tuple[str, str] = ("", ""),
    columns: list[str] | None = None,
    what: str = "rows",
):
    """A Parquet file from outside a run as a DataFrame, through :func:`read_parquet` (the Parquet
    door: bounded on what it decodes to); a FIFO, a folder or a file that is not Parquet is one
    InputError (pyarrow raises several types for those, and words them over several lines)."""
    try:
        return read_parquet(path, max_rows, max_bytes, what, names, columns=columns).to_pandas()
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"not a readable Parquet file ({type(e).__name__}: {one_line(e)})") from None


def _within(n: int, max_bytes: int, path: str | Path, limit_name: str, what: str) -> None:
    if n > max_bytes:
        raise InputError(path, f"{what} {n:,} bytes, over the limit of {max_bytes:,}{_named(limit_name)}")


# ----------------------------------------------------------------------------- JSON


def _int_or_float(text: str):
    """A JSON integer: Python's int up to :data:`MAX_INT_DIGITS` digits, else a float (``10**400``
    becomes inf, refused where a finite number is needed; int() of 4,300 digits would raise)."""
    return int(text) if len(text) <= MAX_INT_DIGITS else float(text)


def _json_children(value: Any) -> list | None:
    """The values a parsed JSON or YAML container holds (None for a scalar)."""
    if isinstance(value, dict):
        return list(value.values())
    if isinstance(value, (list, tuple)):
        return list(value)
    return None


def tree_shape(
    root: Any, children=_json_children, max_nodes: float = math.inf, max_depth: float = math.inf
) -> tuple[float, float]:
    """(depth, nodes) of ``root`` read as a tree, ``children(v)`` giving a container's children (None
    for a leaf): what a recursive walk would meet, computed without recursion in time linear in the
    DISTINCT containers. Why: YAML aliases share one subtree in many places, so a 477-byte file holds
    9**9 values; each container is walked once and its size reused where it reappears. Stops as soon
    as the depth passes ``max_depth`` or the count ``max_nodes`` (returning figures past them); a
    container that holds itself (a recursive alias) is (inf, inf)."""
    memo: dict[int, tuple[float, float]] = {}  # id -> (depth, nodes) of a container walked
    path: dict[int, list] = {}  # id -> children of a container being walked (its ancestors' too)
    stack = [(root, 1, False)]
    while stack:
        v, d, done = stack.pop()
        key = id(v)
        if done:
            deep, size = 1, 1
            for c in path.pop(key):
                cd, cs = memo.get(id(c), (0, 1))  # every container below is walked by now; else a leaf
                deep, size = max(deep, cd + 1), size + cs
            memo[key] = (deep, size)
            if size > max_nodes:
                return deep, size
            continue
        if key in memo:
            continue
        if key in path:
            return math.inf, math.inf
        kids = children(v)
        if kids is None:
            continue
        if d > max_depth or len(memo) + len(path) >= max_nodes:
            return d, len(memo) + len(path) + 1
        path[key] = kids
        stack.append((v, d, True))
        stack.extend((c, d + 1, False) for c in kids)
    return memo.get(id(root), (0, 1))


def depth(value: Any, limit: int = MAX_JSON_DEPTH) -> float:
    """How deeply ``value`` (parsed JSON or YAML) nests (:func:`tree_shape`: no recursion, linear in
    its distinct containers; counting stops past ``limit``; a value holding itself is infinitely deep)."""
    return tree_shape(value, max_depth=limit)[0]


def parse_json(text: str | bytes, source: str | Path) -> Any:
    """A JSON value, refused (InputError naming ``source``) when it is not UTF-8 JSON or nests
    deeper than :data:`MAX_JSON_DEPTH`; long integers are read as floats (:func:`_int_or_float`)."""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        value = json.loads(text, parse_int=_int_or_float)
    except UnicodeDecodeError as e:
        raise InputError(source, f"not UTF-8 text ({e})") from None
    except json.JSONDecodeError as e:
        raise InputError(source, f"invalid JSON (truncated or corrupt?): {e}") from None
    except RecursionError:
        raise InputError(source, f"JSON nested deeper than {MAX_JSON_DEPTH} levels (MAX_JSON_DEPTH)") from None
    except ValueError as e:
        raise InputError(source, f"invalid JSON: {str(e)[:200]}") from None
    if depth(value) > MAX_JSON_DEPTH:
        raise InputError(source, f"JSON nested deeper than {MAX_JSON_DEPTH} levels (MAX_JSON_DEPTH)")
    return value


def read_json(path: str | Path, max_bytes: int = MAX_JSON_BYTES, limit_name: str = "MAX_JSON_BYTES") -> Any:
    """A JSON file: a regular file of at most ``max_bytes`` (:func:`read_bytes`), parsed by
    :func:`parse_json`."""
    data = read_bytes(path, max_bytes, limit_name)
    if not data:
        raise InputError(path, "file is empty")
    return parse_json(data, path)


# ----------------------------------------------------------------------------- YAML


class _Duplicate(ValueError):
    """A key given twice in one JSON object."""


def _no_duplicates(pairs: list) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise _Duplicate(f"key {shown(key)} given twice in one object")
        out[key] = value
    return out


@functools.cache
def _yaml_loader():
    """PyYAML's SafeLoader refusing a key given twice in one mapping (PyYAML keeps the last one
    silently: a second ``seed:`` lower in a file wins unseen); merge keys (``<<``) still merge."""
    import yaml

    class StrictLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                lines: dict = {}
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge":
                        continue  # merged keys: the mapping's own keys override them
                    key = self.construct_object(key_node, deep=True)
                    if not isinstance(key, Hashable):
                        continue  # PyYAML's own error below
                    if key in lines:
                        raise yaml.constructor.ConstructorError(
                            None,
                            None,
                            f"key {shown(key)} given twice (first on line {lines[key]})",
                            key_node.start_mark,
                        )
                    lines[key] = key_node.start_mark.line + 1
            return super().construct_mapping(node, deep)

    return StrictLoader


def _yaml_children(node) -> list | None:
    """The nodes a composed YAML node holds (keys and values; None for a scalar)."""
    import yaml

    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return None


def _yaml_problem(e: Exception) -> str:
    """PyYAML's error as one phrase with its line."""
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    what = " ".join(str(getattr(e, "problem", None) or e).split())[:200]
    return f"line {mark.line + 1}: {what}" if mark is not None else what


def parse_yaml(
    text: str | bytes,
    source: str | Path,
    max_nodes: int = MAX_CONFIG_NODES,
    max_depth: int = MAX_CONFIG_DEPTH + 1,
    limit_name: str = "MAX_CONFIG_NODES",
) -> Any:
    """A YAML value, refused (InputError naming ``source``) when it is not YAML, gives a key twice in
    one mapping, nests deeper than ``max_depth`` or, its aliases expanded, holds more than
    ``max_nodes`` values (counted on the composed nodes, before anything is built: a 477-byte alias
    bomb is refused in milliseconds, :func:`tree_shape`); an alias inside its own anchor too."""
    import yaml

    loader = None
    try:
        loader = _yaml_loader()(text)  # bytes are decoded here (not UTF-8: a YAML error)
        node = loader.get_single_node()
        if node is None:
            return None
        deep, size = tree_shape(node, _yaml_children, max_nodes, max_depth)
        if size == math.inf:
            raise InputError(source, "an alias names a mapping or list that holds it (a recursive YAML alias)")
        if size > max_nodes:
            raise InputError(
                source,
                f"its aliases expand to over {max_nodes:,} values, over the limit{_named(limit_name)}: an alias bomb?",
            )
        if deep > max_depth:
            raise InputError(source, f"nested deeper than {max_depth} levels{_named('MAX_CONFIG_DEPTH')}")
        return loader.construct_document(node)
    except InputError:
        raise
    except yaml.constructor.ConstructorError as e:  # a key given twice, an unknown tag
        raise InputError(source, _yaml_problem(e)) from None
    except yaml.YAMLError as e:
        raise InputError(source, f"not valid YAML: {_yaml_problem(e)}") from None
    except RecursionError:
        raise InputError(source, f"nested deeper than {max_depth} levels{_named('MAX_CONFIG_DEPTH')}") from None
    except ValueError as e:  # an integer of over 4,300 digits
        raise InputError(source, f"not a readable YAML value: {str(e)[:200]}") from None
    finally:
        if loader is not None:
            loader.dispose()


def read_config(path: str | Path) -> Any:
    """A config file as Snakemake reads it (JSON when it parses as JSON, else YAML), through the
    doors: a regular file of at most :data:`MAX_CONFIG_BYTES`, no key given twice (JSON or YAML), no
    alias bomb (:func:`parse_yaml`). Read by the workflow at its start, before anything walks the
    config Snakemake built (which shares aliased subtrees and kept the last of two keys)."""
    data = read_bytes(path, MAX_CONFIG_BYTES, "MAX_CONFIG_BYTES")
    if not data.strip():
        raise InputError(path, "file is empty: a config holds keys at its top level")
    try:
        value = json.loads(data, object_pairs_hook=_no_duplicates, parse_int=_int_or_float)
    except _Duplicate as e:
        raise InputError(path, str(e)) from None
    except RecursionError:
        raise InputError(path, f"nested deeper than {MAX_CONFIG_DEPTH} levels (MAX_CONFIG_DEPTH)") from None
    except ValueError:  # not JSON (JSONDecodeError, UnicodeDecodeError): YAML, as Snakemake reads it next
        value = parse_yaml(data, path)
    else:
        if depth(value, MAX_CONFIG_DEPTH + 1) > MAX_CONFIG_DEPTH + 1:
            raise InputError(path, f"nested deeper than {MAX_CONFIG_DEPTH} levels (MAX_CONFIG_DEPTH)")
    if not isinstance(value, dict):
        raise InputError(path, f"a config holds keys at its top level (a mapping), not {type(value).__name__}")
    if "__use_yte__" in value:
        raise InputError(
            path,
            "a YTE template (__use_yte__): Snakemake ran its Python expressions while loading it, before the "
            "workflow could look; a config is plain YAML or JSON (a config file given to a run is code to trust)",
        )
    return value


# ----------------------------------------------------------------------------- numbers


def finite(value: Any, source: str | Path, where: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a float when it is a number (not a bool, not text), finite and within
    [``low``, ``high``]; else InputError naming ``where``."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    v = float(value) if ok else math.nan
    if not (math.isfinite(v) and low <= v <= high):
        bounds = "" if (low, high) == (-math.inf, math.inf) else f" in [{low:g}, {high:g}]"
        raise InputError(source, f"{where} must be a finite number{bounds}, got {shown(value)}")
    return v


def finite_array(a: np.ndarray, source: str | Path, what: str) -> np.ndarray:
    """``a`` when every value is finite; else InputError naming ``what`` and the first bad index."""
    a = np.asarray(a)
    if a.dtype.kind not in "iuf":
        raise InputError(source, f"{what} must be numbers, not {a.dtype}")
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            first = np.unravel_index(int(np.flatnonzero(bad.ravel())[0]), a.shape)
            raise InputError(
                source, f"{what} holds NaN or inf ({int(bad.sum())} values, first at {tuple(map(int, first))})"
            )
    return a


def count(n: int, bound: int, source: str | Path, what: str, limit_name: str) -> int:
    """``n`` when at most ``bound``; else InputError naming the bound."""
    if n > bound:
        raise InputError(source, f"{n:,} {what}, over the limit of {bound:,} ({limit_name})")
    return n


def local_map(xy: np.ndarray, cls: np.ndarray, source: str | Path, where: str, n_classes: int) -> None:
    """A query's local map read from a table (not through a query file's checks): at most
    :data:`MAX_QUERY_OBJECTS` objects, coordinates finite and within :data:`MAX_LOCAL_COORD`, class
    ids in range."""
    count(len(xy), MAX_QUERY_OBJECTS, source, f"objects in {where}", "MAX_QUERY_OBJECTS")
    if not (np.isfinite(xy).all() and (np.abs(xy) <= MAX_LOCAL_COORD).all()):
        raise InputError(source, f"{where}: x, y must be finite numbers within {MAX_LOCAL_COORD:g} (MAX_LOCAL_COORD)")
    if len(cls) and (cls.min() < 0 or cls.max() >= n_classes):
        raise InputError(source, f"{where}: class_id outside 0..{n_classes - 1}")


# ----------------------------------------------------------------------------- city index


def npz_members(path: str | Path, max_bytes: int = MAX_INDEX_BYTES) -> None:
    """Before ``numpy.load``: ``path`` is a regular file under ``max_bytes`` whose members
    together unpack to at most ``max_bytes`` (a zip bomb is refused before anything is inflated)."""
    regular_file(path, max_bytes, "MAX_INDEX_BYTES")
    members = zip_members(path, MAX_INDEX_MEMBERS, "MAX_INDEX_MEMBERS", "a .npz archive")
    total = sum(i.file_size for i in members)
    if total > max_bytes:
        raise InputError(
            path, f"its arrays unpack to {total:,} bytes, over the limit of {max_bytes:,} (MAX_INDEX_BYTES)"
        )


def zip_members(path: str | Path, max_members: int, limit_name: str, what: str) -> list:
    """The members (``zipfile.ZipInfo``) of a zip archive, listed only once its end record says it
    holds at most ``max_members`` in a central directory of at most 1 kB a member (``zipfile``
    builds an object per member: a 256 MB directory of 5 million empty members costs gigabytes);
    each member stored or deflated (what ``numpy.savez`` and ``torch.save`` write and read)."""
    import zipfile

    try:
        with open(path, "rb") as f:
            end = zipfile._EndRecData(f)  # the end record, zip64's included (the stdlib's own reader)
        if end is None:
            raise zipfile.BadZipFile("no end of central directory")
        count(end[zipfile._ECD_ENTRIES_TOTAL], max_members, path, "members", limit_name)
        count(end[zipfile._ECD_SIZE], 1000 * max_members, path, "bytes of member names", limit_name)
        with zipfile.ZipFile(path) as z:
            members = z.infolist()
    except (zipfile.BadZipFile, OSError, ValueError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(path, f"not {what} ({e})") from None
    odd = [i for i in members if i.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)]
    if odd:
        raise InputError(
            path, f"member {shown(odd[0].filename)} is compressed with method {odd[0].compress_type}: not read"
        )
    return members


def city_index(arrays: dict[str, np.ndarray], path: str | Path, n_classes: int) -> None:
    """A city index's arrays before any kernel sees them: shapes and kinds as :class:`flatlandia.city.index.ViewIndex`
    writes them, every number finite, ``view_ptr`` from 0, non-decreasing, ending at the number of
    seen objects, every seen object and class id in range, ``obj_id`` unique."""
    shapes = {
        "obj_xy": (2, "f"),
        "obj_cls": (1, "iu"),
        "obj_id": (1, "iu"),
        "cam": (2, "f"),
        "view_ptr": (1, "iu"),
        "view_obj": (1, "iu"),
        "idf": (1, "f"),
    }
    for name, (ndim, kinds) in shapes.items():
        a = arrays[name]
        if a.ndim != ndim or a.dtype.kind not in kinds:
            raise InputError(
                path,
                f"{name}: expected a {ndim}-D array of {'floats' if kinds == 'f' else 'integers'}, "
                f"got {a.ndim}-D {a.dtype}",
            )
        finite_array(a, path, name)
    n, views = len(arrays["obj_xy"]), len(arrays["cam"])
    count(n, MAX_INDEX_OBJECTS, path, "objects", "MAX_INDEX_OBJECTS")
    if arrays["obj_xy"].shape[1] != 2 or arrays["cam"].shape[1] != 3:
        raise InputError(path, "obj_xy must be (N, 2) and cam (P, 3)")
    if len(arrays["obj_cls"]) != n or len(arrays["obj_id"]) != n:
        raise InputError(path, f"obj_cls and obj_id must have one entry per object ({n})")
    idf = arrays["idf"]
    if len(idf) < n_classes or (idf < 0).any():
        raise InputError(path, f"idf must hold a weight >= 0 for each of at least {n_classes} classes")
    cls = arrays["obj_cls"]
    if n and (cls.min() < 0 or cls.max() >= len(idf)):
        raise InputError(path, f"obj_cls holds class ids outside 0..{len(idf) - 1}")
    if len(np.unique(arrays["obj_id"])) != n:
        raise InputError(path, "obj_id holds the same object id twice")
    ptr, seen = arrays["view_ptr"], arrays["view_obj"]
    if len(ptr) != views + 1:
        raise InputError(path, f"view_ptr must hold one entry per view and one more ({views + 1}), not {len(ptr)}")
    if ptr[0] != 0 or ptr[-1] != len(seen) or (np.diff(ptr) < 0).any():
        raise InputError(
            path, f"view_ptr must run from 0 to the {len(seen)} seen objects without decreasing (it indexes view_obj)"
        )
    if len(seen) and (seen.min() < 0 or seen.max() >= n):
        raise InputError(path, f"view_obj holds map rows outside 0..{n - 1}")


# ----------------------------------------------------------------------------- maps


def frame_origin(meta: Any, source: str | Path) -> tuple[float, float] | None:
    """A map's metric frame origin (lon0, lat0) from its ``flatlandia`` metadata: None when it
    declares none, else two finite degrees in range; metadata that is not a mapping is refused."""
    if meta is None or meta == {}:
        return None
    if not isinstance(meta, dict):
        raise InputError(source, f"its flatlandia metadata must be a JSON object, not {type(meta).__name__}")
    if meta.get("lon0") is None and meta.get("lat0") is None:
        return None
    lon0 = finite(meta.get("lon0"), source, "metadata lon0", -180.0, 180.0)
    lat0 = finite(meta.get("lat0"), source, "metadata lat0", -90.0, 90.0)
    return lon0, lat0


def frame_matches(lonlat: np.ndarray, xy: np.ndarray, project, origin: tuple[float, float], source: str | Path) -> None:
    """A map whose metadata declares its frame (``origin``, ``project``: (N, 2) lon/lat -> (N, 2) its
    metres) must describe its own data: the origin within :data:`MAX_ORIGIN_OFFSET_M` of its objects
    and its x_m/y_m its lon/lat projected in that frame to :data:`FRAME_TOLERANCE_M` (a forged lon0
    moves every answer's lon/lat, not its metres). Longitudes are compared wrapped
    (:func:`lon_offset`): a map across the antimeridian lies beside its origin, not a turn away."""
    if not len(lonlat):
        return
    east = float(np.mean(lon_offset(lonlat[:, 0], origin[0])))
    lat = float(np.mean(lonlat[:, 1]))
    k = 6371008.8 * math.pi / 180
    off = math.hypot(east * k * math.cos(math.radians(lat)), (lat - origin[1]) * k)
    if not off <= MAX_ORIGIN_OFFSET_M:
        raise InputError(
            source,
            f"its metadata puts the frame's origin (lon0 {origin[0]:g}, lat0 {origin[1]:g}) {off / 1000:,.0f} km from its "
            f"objects (at most {MAX_ORIGIN_OFFSET_M / 1000:g} km): the metadata does not describe this map",
        )
    with np.errstate(all="ignore"):
        proj = np.asarray(project(lonlat), float).reshape(-1, 2)
        worst = float(np.max(np.hypot(*(proj - xy).T)))
    if not worst <= FRAME_TOLERANCE_M:
        raise InputError(
            source,
            f"its x_m/y_m are not its lon/lat in the frame its metadata declares (lon0 {origin[0]:g}, lat0 {origin[1]:g}): "
            f"up to {worst:.3g} m apart (at most {FRAME_TOLERANCE_M:g} m)",
        )


def class_counts(cls: np.ndarray, source: str | Path, names: list[str]) -> None:
    """Refuse a scene map with more than :data:`MAX_CLASS_OBJECTS` objects of one class."""
    counts = np.bincount(np.asarray(cls, np.int64), minlength=len(names))
    worst = int(np.argmax(counts)) if len(counts) else 0
    if len(counts) and counts[worst] > MAX_CLASS_OBJECTS:
        raise InputError(
            source,
            f"{int(counts[worst]):,} objects of class {names[worst]!r}, over the limit of {MAX_CLASS_OBJECTS} "
            "(MAX_CLASS_OBJECTS): a map that large is searched through a city index (results/city/{n}/index)",
        )


def unique_ids(ids: np.ndarray, source: str | Path, what: str = "obj_idx") -> None:
    """Refuse an id given to two objects (a match would name either)."""
    values, counts = np.unique(ids, return_counts=True)
    twice = values[counts > 1]
    if len(twice):
        listed = ", ".join(str(int(v)) for v in twice[:5]) + (" ..." if len(twice) > 5 else "")
        raise InputError(source, f"{what} {listed} given to more than one object: each object needs its own {what}")


# ----------------------------------------------------------------------------- learned priors


def map_size_calibration(d: Any, source: str | Path, max_shift: float, max_per_log_odds: float) -> None:
    """A city's map-size correction (rule city_calibration's record,
    :class:`flatlandia.solver.calibration.MapSize` under key ``map_size``): ``reference_objects``
    >= 1; ``frame`` and ``sequence`` each a ``shift`` in [0, ``max_shift``] and a ``per_log_odds``
    in [0, ``max_per_log_odds``]; ``answers`` a count."""
    if not isinstance(d, dict) or not isinstance(d.get("map_size"), dict):
        raise InputError(source, "expected a JSON object with a map_size object (rule city_calibration's record)")
    map_size(d["map_size"], source, max_shift, max_per_log_odds)


def map_size(m: Any, source: str | Path, max_shift: float, max_per_log_odds: float, where: str = "map_size") -> None:
    """A map-size correction's object (``where``: where it sits in its file): only its keys,
    ``reference_objects`` in [1, 10^9], each term an object of a ``shift`` and a ``per_log_odds``
    within their bounds, ``answers`` a count."""
    json_object(m, source, where, ("reference_objects", "frame", "sequence", "answers"))
    finite(m.get("reference_objects"), source, f"{where} reference_objects", 1.0, 1e9)
    for kind in ("frame", "sequence"):
        term = m.get(kind)
        if not isinstance(term, dict):
            raise InputError(source, f"{where} {kind} must be an object with shift and per_log_odds, got {shown(term)}")
        json_object(term, source, f"{where} {kind}", ("shift", "per_log_odds"))
        finite(term.get("shift"), source, f"{where} {kind} shift", 0.0, max_shift)
        finite(term.get("per_log_odds"), source, f"{where} {kind} per_log_odds", 0.0, max_per_log_odds)
    n = m.get("answers")
    if not isinstance(n, int) or isinstance(n, bool) or not 0 <= n <= MAX_RECORD_COUNT:
        raise InputError(source, f"{where} answers must be a count of answers, got {shown(n)}")


def learned_priors(d: Any, source: str | Path, n_features: int, version: int) -> None:
    """A solver priors JSON (:class:`flatlandia.solver.learned_priors.LearnedPriors`) of format
    ``version`` (an older one: one error naming its format and the rule that rewrites it): an
    object of exactly :data:`PRIORS_KEYS` (each null where not fitted: ``{}`` is no "no priors");
    ``scale_prior`` null or (mean, std) finite with std > 0; ``verifier`` null or ``weights``
    (within :data:`MAX_LOGIT_WEIGHT`), ``mean``, ``scale`` (within :data:`MAX_LOCAL_COORD`) of
    ``n_features`` finite numbers each, every scale > 0; ``features`` a list of names;
    ``likelihood``, ``calibration`` and ``noise`` null or objects (checked field by field where they
    are read: ``LikelihoodModel.from_dict``, ``Calibration.from_dict``, ``NoiseModel.from_dict``)."""
    if not isinstance(d, dict):
        raise InputError(source, "expected a JSON object with scale_prior and verifier")
    found = d.get("format", 1)
    if type(found) is not int or found != version:
        said = shown(found) if "format" in d else "1 (no 'format' key: written before the one noise model)"
        raise InputError(
            source,
            f"a solver priors file of format {said}, this solver reads format {version}: rule solver_priors "
            "rewrites it (snakemake --forcerun solver_priors, or delete the file)",
        )
    json_object(d, source, "the learned priors", PRIORS_KEYS)
    absent = [k for k in PRIORS_KEYS if k not in d]
    if absent:
        raise InputError(
            source, f"the learned priors lack {', '.join(absent)} (null where not fitted): not a priors file"
        )
    for key in ("likelihood", "calibration", "noise"):
        if d[key] is not None:
            json_object(d[key], source, key)
    names = d["features"]
    if not isinstance(names, list) or not all(isinstance(x, str) for x in names):
        raise InputError(source, f"features must be a list of feature names, got {shown(names)}")
    sp = d.get("scale_prior")
    if sp is not None:
        if not isinstance(sp, list) or len(sp) != 2:
            raise InputError(source, f"scale_prior must be [mean, std] of log metres per unit, got {shown(sp)}")
        finite(sp[0], source, "scale_prior mean", -50.0, 50.0)
        std = finite(sp[1], source, "scale_prior std", 0.0, 50.0)
        if std <= 0:
            raise InputError(source, f"scale_prior std must be > 0, got {shown(sp[1])}")
    v = d.get("verifier")
    if v is not None:
        if not isinstance(v, dict):
            raise InputError(source, "verifier must be an object with weights, mean and scale")
        json_object(v, source, "verifier", ("weights", "mean", "scale"))
        for key in ("weights", "mean", "scale"):
            values = v.get(key)
            if not isinstance(values, list) or len(values) != n_features:
                raise InputError(
                    source, f"verifier {key} must list {n_features} numbers (one per feature), got {shown(values)}"
                )
            low, high = {"weights": (-MAX_LOGIT_WEIGHT, MAX_LOGIT_WEIGHT), "scale": (0.0, MAX_LOCAL_COORD)}.get(
                key, (-MAX_LOCAL_COORD, MAX_LOCAL_COORD)
            )
            for i, x in enumerate(values):
                finite(x, source, f"verifier {key}[{i}]", low, high)
                if key == "scale" and x <= 0:
                    raise InputError(source, f"verifier scale[{i}] must be > 0, got {shown(x)}")


# ----------------------------------------------------------------------------- typed records

#: levels of inputs ``flatlandia audit PATH --tree`` follows (the workflow has 53 rules: a run's
#: chains are shorter unless a rule reads its own rule's outputs); deeper ones are one line saying so:
#: a chain of 100,000 tampered records would otherwise print 10^10 characters of indentation
MAX_TREE_DEPTH = 100
#: a manifest read back (``flatlandia audit``'s fallback for a results folder copied without its
#: logs): on disk and what its columns decode to, and its rows, one per artifact (a run's: a few
#: thousand rows of under 1 kB each, the inputs' lists aside)
MAX_MANIFEST_BYTES = 256 * MB
MAX_MANIFEST_ROWS = 1_000_000
#: largest |weight| or |intercept| of a fitted logistic map (the answers' calibration, the likelihood
#: model's detection probability, the verifier's linear score): their features are bounded (log-odds
#: within 20, log counts within 10, shares within 1), so 1,000 already makes every answer 0 or 1
#: (the fitted ones, scikit-learn's L2 with C = 1, are single digits: the views' share, 7.3)
MAX_LOGIT_WEIGHT = 1_000.0
#: a camera's heading in degrees, either way (the workflow writes (-180, 180]; EXIF's: GEOTAG_RANGES)
MAX_ANGLE_DEG = 360.0
#: a scene's queries table (queries.parquet) on disk and unpacked (a published scene's: under 100 kB;
#: MAX_QUERIES queries of MAX_QUERY_OBJECTS objects in both local maps: about 35 MB)
MAX_QUERY_TABLE_BYTES = 64 * MB
#: scenes of a results folder's benchmark record (the benchmark: 20)
MAX_SCENES = 1_000
#: the keys of a learned priors JSON (``LearnedPriors.to_dict`` writes every one, null where not fitted)
PRIORS_KEYS = ("format", "scale_prior", "verifier", "features", "likelihood", "calibration", "noise")
#: a count in a record (answers, detections a model was fitted on)
MAX_RECORD_COUNT = 10**12
#: the splits a queries table may name
SPLITS = ("train", "val", "test")


def json_object(value: Any, source: str | Path, where: str, keys: tuple[str, ...] | None = None) -> dict:
    """``value`` when it is a JSON object with no key outside ``keys`` (None: any); a list, a
    number or a text where an object is expected is refused naming ``where``."""
    if not isinstance(value, dict):
        raise InputError(source, f"{where} must be a JSON object, got {shown(value)}")
    unknown = sorted(str(k) for k in value if keys is not None and k not in keys)
    if unknown:
        raise InputError(source, f"{where}: unknown key(s) {shown(unknown)}; expected {', '.join(keys or ())}")
    return value


def numbers(
    value: Any, source: str | Path, where: str, n: int | None = None, low: float = -math.inf, high: float = math.inf
) -> tuple[float, ...]:
    """``value`` as floats when it is a JSON list of ``n`` numbers (None: any count), each finite
    within [``low``, ``high``]; a text is no list ("1234" is not the digits 1, 2, 3, 4)."""
    if not isinstance(value, list) or (n is not None and len(value) != n):
        count_text = f"{n} numbers" if n is not None else "numbers"
        raise InputError(source, f"{where} must be a list of {count_text}, got {shown(value)}")
    return tuple(finite(x, source, f"{where}[{i}]", low, high) for i, x in enumerate(value))


def whole(value: Any, source: str | Path, where: str, low: int = 0, high: int = MAX_RECORD_COUNT) -> int:
    """``value`` when it is an integer (not a bool, a float or a text) within [``low``, ``high``]."""
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise InputError(source, f"{where} must be an integer in [{low:,}, {high:,}], got {shown(value)}")
    return value


def lon_offset(lon: Any, lon0: float) -> np.ndarray:
    """Degrees of longitude from ``lon0`` east, wrapped into [-180, 180): across the antimeridian
    179.9 is 0.2 degrees west of -179.9, not 359.8 east."""
    return (np.asarray(lon, float) - lon0 + 180.0) % 360.0 - 180.0


def lonlat_degrees(lonlat: np.ndarray, source: str | Path, where: str = "lon/lat") -> np.ndarray:
    """``lonlat`` (N, 2) when every value is a finite degree (lon in [-180, 180], lat in [-90, 90])."""
    a = np.asarray(lonlat, float).reshape(-1, 2)
    if not (np.isfinite(a).all() and (np.abs(a[:, 0]) <= 180).all() and (np.abs(a[:, 1]) <= 90).all()):
        raise InputError(source, f"{where} must be finite degrees (lon in [-180, 180], lat in [-90, 90])")
    return a


def columns(table: Any, names: list[str] | tuple[str, ...], source: str | Path) -> None:
    """Refuse a table without each of ``names`` (one line listing the missing ones)."""
    missing = [c for c in names if c not in table.columns]
    if missing:
        raise InputError(source, f"missing column(s) {', '.join(missing)}")


def ground_truth(table: Any, source: str | Path, label, obj_ids: np.ndarray | None = None) -> None:
    """Query cameras read from a table (a queries.parquet, an export's ground_truth.csv): the truth a
    score measures against, the training cameras the solver's priors come from. Columns ``token``,
    ``split`` (one of :data:`SPLITS`), ``x_m``, ``y_m`` (finite metres within
    :data:`MAX_LOCAL_COORD`), ``theta_deg`` (finite, within :data:`MAX_ANGLE_DEG`) and ``ref_idx``
    (the ids each camera saw: integers among ``obj_ids``, the map's, when given). A NaN truth is
    refused, not scored as a failure: the denominator and every row's error would change without a
    word. ``label(i)``: row i as the error line names it (a CSV's line, a Parquet's row, its token)."""
    columns(table, ("token", "split", "x_m", "y_m", "theta_deg", "ref_idx"), source)
    count(len(table), MAX_QUERIES, source, "queries", "MAX_QUERIES")
    split = table["split"].astype(str).to_numpy()
    bad = np.flatnonzero(~np.isin(split, SPLITS))
    if len(bad):
        i = int(bad[0])
        raise InputError(source, f"{label(i)}, column split: {shown(split[i])} is not one of {', '.join(SPLITS)}")
    for c, bound in (("x_m", MAX_LOCAL_COORD), ("y_m", MAX_LOCAL_COORD), ("theta_deg", MAX_ANGLE_DEG)):
        try:
            v = np.asarray(table[c].to_numpy(), float)
        except (TypeError, ValueError):
            v = np.array([_float_or_nan(x) for x in table[c]])
        bad = np.flatnonzero(~(np.abs(v) <= bound))  # NaN compares False
        if len(bad):
            i, cell = int(bad[0]), table[c].iloc[int(bad[0])]
            cell = cell.item() if isinstance(cell, np.generic) else cell  # nan, not np.float64(nan)
            raise InputError(
                source,
                f"{label(i)}, column {c}: {shown(cell)} is not a finite number within {bound:g} ({len(bad)} row(s))",
            )
    known = None if obj_ids is None else set(np.asarray(obj_ids).tolist())
    for i, seen in enumerate(table["ref_idx"]):
        ids = np.asarray(seen if seen is not None else [])
        if ids.ndim != 1 or (len(ids) and ids.dtype.kind not in "iu"):
            raise InputError(source, f"{label(i)}, column ref_idx: object ids must be integers, got {shown(seen)}")
        stray = [int(o) for o in ids.tolist() if known is not None and int(o) not in known]
        if stray:
            raise InputError(
                source, f"{label(i)}, column ref_idx: object id(s) {shown(stray)} are none of the map's objects"
            )


def _float_or_nan(x: Any) -> float:
    """A table cell as a float: a number, else NaN (refused by the caller as not a finite number)."""
    ok = isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))
    return float(x) if ok else math.nan
