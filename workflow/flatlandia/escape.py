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
