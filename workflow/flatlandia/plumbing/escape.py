"""Text written into LaTeX, Markdown or HTML, escaped for that format: one function per format.

Why: values in the tables and pages come from files a user or a download controls (the scene
sheet's ``city`` and ``name``, scene ids, labels in result files). Written verbatim, a city of
``\\input{secret.tex}`` runs in the paper's LaTeX, ``<img src=x onerror=...>`` runs in the
Snakemake report that renders the Markdown as HTML, and a ``|`` splits a table cell. Every writer
of ``.tex``, ``.md`` and ``.html`` passes its values (cells, user text) through the function of
its format; the writers' own templates (headings, notes, deliberate markup) stay as written.
Each function takes any value (``str()`` of it) and escapes in one pass, so nothing is escaped twice.
:func:`mathtext` does the same for matplotlib's titles and labels (``$`` starts its TeX-like math),
:func:`terminal` for a name printed to a terminal (an ESC in a record's name would clear the screen),
:func:`csv_cell` for a CSV cell a spreadsheet opens.
"""

from __future__ import annotations

import html as _html
import re
import unicodedata

#: the ten LaTeX specials, and ``< > |`` (which print as other glyphs in LaTeX's default font
#: encoding); a line break would end a table row or a paragraph, so it becomes a space
_LATEX = {
    "\\": r"\textbackslash{}",
    "{": r"\{",
    "}": r"\}",
    "$": r"\$",
    "&": r"\&",
    "#": r"\#",
    "^": r"\textasciicircum{}",
    "_": r"\_",
    "~": r"\textasciitilde{}",
    "%": r"\%",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
    "\r\n": " ",
    "\n": " ",
    "\r": " ",
}
_LATEX_RE = re.compile("|".join(re.escape(k) for k in sorted(_LATEX, key=len, reverse=True)))

#: Markdown: what starts HTML or an entity becomes an entity; what starts markup (emphasis, code,
#: links, images), the table's cell separator and the escape character itself get a backslash (all
#: of them escapable in CommonMark, GitHub's Markdown and Python-Markdown's tables)
_MARKDOWN = {
    "&": "&amp;",
    "<": "&lt;",
    ">": "&gt;",
    "\\": "\\\\",
    "|": "\\|",
    "*": "\\*",
    "`": "\\`",
    "[": "\\[",
    "]": "\\]",
    "\r\n": " ",
    "\n": " ",
    "\r": " ",
}
_MARKDOWN_RE = re.compile("|".join(re.escape(k) for k in sorted(_MARKDOWN, key=len, reverse=True)) + "|_")


def latex(text) -> str:
    """``text`` as literal LaTeX text (a table cell, a caption): every special escaped."""
    return _LATEX_RE.sub(lambda m: _LATEX[m.group(0)], str(text))


def markdown(text) -> str:
    """``text`` as literal Markdown inline text (a table cell, a value in a sentence or heading):
    on one line, one cell, no HTML, entity, link, image, code or emphasis of its own.

    ``_`` between two letters or digits cannot start or end emphasis (``R_30``, ``solver_gt_gtbb``):
    it stays as written, so the file reads as before; any other ``_`` gets a backslash."""
    s = str(text)

    def sub(m: re.Match) -> str:
        c = m.group(0)
        if c != "_":
            return _MARKDOWN[c]
        i = m.start()
        inert = 0 < i < len(s) - 1 and s[i - 1].isalnum() and s[i + 1].isalnum()
        return "_" if inert else "\\_"

    return _MARKDOWN_RE.sub(sub, s)


def html(text) -> str:
    """``text`` as HTML text or a quoted attribute value: ``& < > " '`` as entities."""
    return _html.escape(str(text), quote=True)


#: Unicode categories of the characters nobody sees as themselves: controls (Cc: C0, DEL, C1; ESC
#: and the C1 CSI start a terminal's commands, U+0085 ends a line), format characters (Cf: the bidi
#: overrides and isolates U+202A-202E and U+2066-2069 reorder what follows, U+200B-200F are
#: zero-width, U+FEFF), lone surrogates (Cs) and the line and paragraph separators (Zl, Zp)
HIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Zl", "Zp"})
#: every character but printable ASCII: only these are looked up (plain text passes in one scan)
_NOT_ASCII_PRINTABLE = re.compile(r"[^\x20-\x7e]")


def hidden(text) -> str | None:
    """The first character of ``text`` in :data:`HIDDEN_CATEGORIES` (None: there is none)."""
    for m in _NOT_ASCII_PRINTABLE.finditer(str(text)):
        if unicodedata.category(m.group(0)) in HIDDEN_CATEGORIES:
            return m.group(0)
    return None


def codepoint(c: str) -> str:
    """One character as Python writes it escaped: ``\\x1b``, ``\\u202e``, ``\\U000e0001``."""
    n = ord(c)
    return f"\\x{n:02x}" if n < 0x100 else f"\\u{n:04x}" if n < 0x10000 else f"\\U{n:08x}"


def terminal(text) -> str:
    """``text`` (one field: a name, a path, a value read from a file) as a terminal shows it
    literally: every character of :data:`HIDDEN_CATEGORIES`, line breaks and tabs included, written as
    its escape (``\\x1b``, ``\\u202e``). Why: the names ``flatlandia audit`` prints come from records
    anyone can edit; raw, an ESC clears the screen, an OSC retitles the terminal, U+202E shows
    ``gpj.exe`` as ``exe.jpg``, and a line break forges a line of the command's own."""

    def sub(m: re.Match) -> str:
        c = m.group(0)
        return codepoint(c) if unicodedata.category(c) in HIDDEN_CATEGORIES else c

    return _NOT_ASCII_PRINTABLE.sub(sub, str(text))


def mathtext(text) -> str:
    """``text`` for a matplotlib title or label: ``$`` would start mathtext (which parses TeX-like
    commands and fails on unknown ones), so it is escaped."""
    return str(text).replace("$", r"\$")


#: what starts a formula in a spreadsheet (Excel, LibreOffice, Google Sheets) opening a CSV: ``=``,
#: ``+``, ``@``, ``-``, a tab or a line break, and their full-width forms (which some of them fold)
_FORMULA_START = frozenset("=+@-\t\r\n\uff1d\uff0b\uff20\uff0d")
#: one term of a spreadsheet's arithmetic made only of the characters a token holds: a number (``3``,
#: ``1.5``, the ``1e`` of ``1e-5``), a cell reference (``A1``, ``XFD1048576``, R1C1's ``R2C3``) or
#: ``TRUE``/``FALSE``; a ``-`` before a chain of them (``-2-3``, ``-A1-B1``) is a formula
_TERM = r"(?:[0-9]+(?:\.[0-9]*)?(?:[eE][0-9]*)?|\.[0-9]+|[A-Za-z]{1,3}[0-9]{1,7}|[Rr][0-9]*[Cc][0-9]*|(?i:true|false))"
#: a cell starting with ``-`` that is not a formula, passed unchanged: a plain number
#: (``-1.5``, ``-3e-5``, ``-.5``) or a Mapillary image key, the published tokens' form that starts
#: with ``-``: 22 characters of base64url (``[A-Za-z0-9_-]``, ``-AB21Af_LPev08UY_96ptQ``; every
#: published token is 15 or 16 digits or 22 such characters) unless they are arithmetic of terms
#: (:data:`_TERM`: ``-A1-B1-C1-D1-E1-F1-G12`` is 22 characters too). Anything else (``-2-3``,
#: ``-A1-B1``, ``-1+2``, ``-SUM(A1)``, a shorter or longer word) is quoted.
_PLAIN_DASHED = re.compile(
    rf"-(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?!(?:-+{_TERM})+\Z)-[A-Za-z0-9_\-]{{21}}", re.ASCII
)
#: a PROJ string (the export's ``crs``: ``+proj=tmerc +lat_0=... +no_defs``) of plain characters: no
#: call, no reference, no ``|`` can be in it, so it passes unchanged
_PROJ = re.compile(r"\+proj=[A-Za-z0-9_.=+ \-]*", re.ASCII)


def csv_cell(text) -> str:
    """``text`` as a CSV cell no spreadsheet runs: a cell that starts a formula (:data:`_FORMULA_START`;
    one starting with ``-`` unless it is a plain number or a token, :data:`_PLAIN_DASHED`; one
    starting with ``+`` unless it is a plain PROJ string, :data:`_PROJ`) gets
    a leading ``'``, which spreadsheets show as text; every other cell is unchanged. Why: the
    export's cells come from files a user or a download controls (query tokens, the scene sheet's
    city), and ``=HYPERLINK(...)`` or ``+cmd|...`` would run when the CSV is opened.
    :func:`csv_cell_read` undoes it."""
    s = str(text)
    return "'" + s if _runs(s) else s


def _runs(s: str) -> bool:
    """Whether a spreadsheet would run the cell ``s``, or ``s`` is such a cell already made text
    (leading ``'`` s before it: escaped again, so :func:`csv_cell_read` gets back every value)."""
    rest = s.lstrip("'")
    if not rest or rest[0] not in _FORMULA_START:
        return False
    return not ((rest[0] == "-" and _PLAIN_DASHED.fullmatch(rest)) or (rest == s and _PROJ.fullmatch(s)))


def csv_cell_read(text: str) -> str:
    """A cell as :func:`csv_cell` wrote it, back to its value (``'=x`` -> ``=x``; ``'abc`` stays)."""
    if text.startswith("'") and csv_cell(text[1:]) == text:
        return text[1:]
    return text
