"""Names read from untrusted files become parts of paths: one check at the door.

Query tokens (``local_maps.json``, ``tokens.txt``), image names (a user's folder, ``metadata.csv``)
and scene ids end up in output paths (``masks/<name>.png``, ``queries/figures/<token>.png``).
A name that is not one plain path component (``../../x``, ``/x``, ``a/b``) would point outside the
folder it is joined to, so every reader checks the names it returns with :func:`plain_name`, and
writers that join a name to a folder go through :func:`child` (a second check where it matters).
A name is also refused when it holds a character nobody sees as itself (C0 and C1 controls, bidi
overrides and isolates, zero-width characters: :data:`flatlandia.plumbing.escape.HIDDEN_CATEGORIES`):
``photo\u202egpj.exe`` would be listed as ``photoexe.jpg``. The published tokens are ``[A-Za-z0-9_-]``.
"""

from __future__ import annotations

import unicodedata
from pathlib import Path

from flatlandia.plumbing import escape
from flatlandia.plumbing.errors import InputError

#: longest name accepted, in UTF-8 bytes (file systems allow 255; room for a suffix)
MAX_NAME_BYTES = 200


def name_problem(name) -> str | None:
    """Why ``name`` cannot be one plain path component (None: it can)."""
    if not isinstance(name, str):
        return f"not text ({type(name).__name__})"
    if not name.strip():
        return "empty"
    if name in (".", ".."):
        return "'.' or '..'"
    if "/" in name or "\\" in name:
        return "holds '/' or '\\' (a folder)"
    if len(name) > MAX_NAME_BYTES:  # each character is at least one byte; a long text is never scanned
        return f"longer than {MAX_NAME_BYTES} bytes"
    c = escape.hidden(name)
    if c is not None:  # before encode(): a lone surrogate has no UTF-8
        label = unicodedata.name(c, "")
        return f"holds a control or invisible character ({escape.codepoint(c)}{': ' + label if label else ''})"
    if len(name.encode()) > MAX_NAME_BYTES:
        return f"longer than {MAX_NAME_BYTES} bytes"
    return None


def plain_name(name, source: str | Path, what: str = "name") -> str:
    """``name`` when it is one plain path component, else :class:`InputError` naming ``source``
    (the file or folder it was read from), what it is, and why it is refused."""
    why = name_problem(name)
    if why:
        raise InputError(
            source,
            f"{what} {_shown(name)} is refused: {why}; a name must be one plain file name "
            f"(no folders, no '..', no '/' or '\\', no control or invisible characters, at most {MAX_NAME_BYTES} bytes)",
        )
    return name


def _shown(name) -> str:
    from flatlandia.plumbing.validate import shown

    return shown(name)


def child(folder: str | Path, name, suffix: str = "", what: str = "name") -> Path:
    """``folder / (name + suffix)``, refused unless ``name`` is one plain component (the path can
    then never leave ``folder``)."""
    return Path(folder) / (plain_name(name, folder, what) + suffix)
