"""A PLY file's header, checked before a reader allocates for it.

Why: a PLY header declares its element counts, and readers (open3d among them) allocate for what
is declared; a published file whose header claims 4e9 vertices ends in a RuntimeError deep in
open3d, or exhausts memory. :func:`check_header` reads the header alone and refuses counts the
file cannot hold, naming the file, before any reader touches the body.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from flatlandia.plumbing.errors import InputError

#: bytes of each PLY scalar type
TYPE_BYTES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1,
    "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip
FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
#: a header longer than this is not a PLY header
MAX_HEADER_BYTES = 64 * 1024
#: fewest bytes one ascii row can take ("0\n")
MIN_ASCII_ROW_BYTES = 2


@dataclass(frozen=True)
class Element:
    name: str
    count: int
    row_bytes: int | None  # None when a list property makes rows variable


@dataclass(frozen=True)
class Header:
    format: str
    elements: tuple[Element, ...]
    header_bytes: int

    def count(self, name: str) -> int:
        return next((e.count for e in self.elements if e.name == name), 0)


def _parse(path: Path, head: bytes) -> Header:
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputError(
            path, f"not a PLY file (no 'ply' magic or no end_header in its first {MAX_HEADER_BYTES} bytes)"
        )
    newline = head.find(b"\n", end)
    header_bytes = (newline if newline >= 0 else end + len(b"end_header")) + 1
    try:
        lines = head[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError as e:
        raise InputError(path, f"PLY header is not ASCII text ({e})") from e
    fmt, elements, current = None, [], None
    for n, line in enumerate(lines, start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                if current:
                    elements.append(current)
                count = int(words[2])
                if count < 0:
                    raise ValueError("negative count")
                current = [words[1], count, 0]
            elif words[0] == "property" and current is not None:
                if words[1] == "list":
                    current[2] = None
                elif current[2] is not None:
                    current[2] += TYPE_BYTES[words[1]]
            else:
                raise ValueError(f"unexpected keyword {words[0]!r}")
        except (IndexError, KeyError, ValueError) as e:
            raise InputError(path, f"malformed PLY header, line {n} {line.strip()!r} ({e})") from e
    if current:
        elements.append(current)
    if fmt not in FORMATS:
        raise InputError(path, f"PLY format {fmt!r} is none of {', '.join(FORMATS)}")
    return Header(fmt, tuple(Element(*e) for e in elements), header_bytes)


def check_header(path: str | Path) -> Header:
    """The header of the PLY ``path``, refused (:class:`InputError`) unless the body can hold what
    it declares: binary rows of fixed size must fit the bytes after the header exactly or more
    (some writers pad), ascii rows take at least two bytes each."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file is missing")
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER_BYTES)
    header = _parse(path, head)
    body = path.stat().st_size - header.header_bytes
    if header.format == "ascii":
        rows = sum(e.count for e in header.elements)
        if rows * MIN_ASCII_ROW_BYTES > body:
            raise InputError(
                path,
                f"PLY header declares {rows} rows but the ascii body holds only {body} bytes (truncated or forged)",
            )
        return header
    need = 0
    for e in header.elements:
        need += e.count * (e.row_bytes if e.row_bytes is not None else 1)
        if need > body:
            raise InputError(
                path,
                f"PLY header declares {e.count} {e.name} rows"
                + (f" of {e.row_bytes} bytes" if e.row_bytes is not None else "")
                + f", more than the {body} bytes after its header can hold (truncated or forged)",
            )
    return header
