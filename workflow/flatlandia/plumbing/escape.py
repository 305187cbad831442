"""Text written into LaTeX, Markdown or HTML, escaped for that format: one function per format.

Why: values in the tables and pages come from files a user or a download controls (the scene
sheet's ``city`` and ``name``, scene ids, labels in result files). Written verbatim, a city of
``\\input{secret.tex}`` runs in the paper's LaTeX, ``<img src=x onerror=...>`` runs in the
Snakemake report that renders the Markdown as HTML, and a ``|`` splits a table cell. Every writer
of ``.tex``, ``.md`` and ``.html`` passes its values (cells, user text) through the function of
its format; the writers' own templates (headings, notes, deliberate markup) stay as written.
Each function takes any value (``str()`` of it) and escapes in one pass, so nothing is escaped twice.
:func:`mathtext` does the same for matplotlib's titles and labels (``$`` starts its TeX-like math).
"""

from __future__ import annotations

import html as _html
import re

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


def mathtext(text) -> str:
    """``text`` for a matplotlib title or label: ``$`` would start mathtext (which parses TeX-like
    commands and fails on unknown ones), so it is escaped."""
    return str(text).replace("$", r"\$")


#: what starts a formula in a spreadsheet (Excel, LibreOffice, Google Sheets) opening a CSV: ``=``,
#: ``+``, ``@``, ``-``, a tab or a line break, and their full-width forms (which some of them fold)
_FORMULA_START = frozenset("=+@-\t\r\n\uff1d\uff0b\uff20\uff0d")
#: a cell starting with ``-`` that holds only these is a word or a number, not a formula: the
#: published Mapillary tokens (``-AB21Af_LPev08UY_96ptQ``) and negative numbers pass unchanged
_PLAIN_DASHED = re.compile(r"-[A-Za-z0-9_.\-]*", re.ASCII)
#: a PROJ string (the export's ``crs``: ``+proj=tmerc +lat_0=... +no_defs``) of plain characters: no
#: call, no reference, no ``|`` can be in it, so it passes unchanged
_PROJ = re.compile(r"\+proj=[A-Za-z0-9_.=+ \-]*", re.ASCII)


def csv_cell(text) -> str:
    """``text`` as a CSV cell no spreadsheet runs: a cell that starts a formula (:data:`_FORMULA_START`;
    one starting with ``-`` only when it is not a plain word or number, :data:`_PLAIN_DASHED`; one
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
