"""Zip archives the fetch tests build: :func:`make_zip` (one helper for the tests of
flatlandia.data.fetch: good archives, crafted ones, members of any unix file type)."""

from __future__ import annotations

import stat
import zipfile
from collections.abc import Iterable
from pathlib import Path


def add_member(z: zipfile.ZipFile, name: str, data: bytes = b"x", kind: int = stat.S_IFREG) -> None:
    """A member with unix file type ``kind`` (regular file, symlink, device...)."""
    info = zipfile.ZipInfo(name)
    info.create_system = 3  # unix: the type bits below are honoured by unzip tools
    info.external_attr = (kind | 0o644) << 16
    z.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED)


def make_zip(path: Path, members: dict[str, bytes] | Iterable[tuple]) -> Path:
    """The zip archive ``path`` holding ``members``: {name: bytes}, or (name, bytes[, unix file
    type]) tuples (:func:`add_member`); returns ``path``."""
    with zipfile.ZipFile(path, "w") as z:
        for member in members.items() if isinstance(members, dict) else members:
            add_member(z, *member)
    return path
