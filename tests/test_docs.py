"""The documentation holds together: the README fits on a screen, every relative link of the README
and of docs/*.md reaches a file (and, with a #fragment, a heading of it), every docs/... path they
name exists, and the README's two times are the ones docs/timings.md records."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
#: the README's length, in lines (issue 37: "a README that fits on a screen", the rest in docs/)
README_MAX_LINES = 250

LINK = re.compile(r"\]\(([^)\s]+)\)")
DOCS_PATH = re.compile(r"(?<![\w/.])docs/[\w./-]*[\w/]")


def prose(text: str) -> str:
    """``text`` without fenced code blocks and inline code spans (code is not a link)."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lowercase, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a Markdown page (outside code blocks), duplicates numbered as GitHub does."""
    seen: dict[str, int] = {}
    out = set()
    for line in re.sub(r"^```.*?^```", "", page.read_text(), flags=re.M | re.S).splitlines():
        m = re.match(r"#{1,6} (.+)", line)
        if m:
            s = slug(m.group(1))
            out.add(s if s not in seen else f"{s}-{seen[s]}")
            seen[s] = seen.get(s, 0) + 1
    return out


def test_the_readme_fits_on_a_screen():
    n = len((REPO / "README.md").read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (at most {README_MAX_LINES}): move detail to docs/"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_relative_link_reaches_a_file_and_heading(page):
    broken = []
    for target in LINK.findall(prose(page.read_text())):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        path, _, fragment = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no such file")
        elif fragment and file.suffix == ".md" and fragment not in anchors(file):
            broken.append(f"{target}: no heading '#{fragment}' in {file.relative_to(REPO)}")
    assert not broken, f"{page.relative_to(REPO)}: " + "; ".join(broken)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_docs_path_named_exists(page):
    named = set(DOCS_PATH.findall(page.read_text()))
    missing = sorted(p for p in named if not (REPO / p.rstrip("/")).exists())
    assert not missing, f"{page.relative_to(REPO)} names {missing}, which do not exist"


def test_the_readmes_times_are_the_timings_pages():
    """The two times the README quotes (the default run, `make test`) are the bold values of their
    rows in docs/timings.md, so a new measurement is written in one row and one README cell."""
    timings = (REPO / "docs" / "timings.md").read_text()
    readme = (REPO / "README.md").read_text()
    rows = [line for line in timings.splitlines() if line.startswith("| **")]
    assert len(rows) == 2, rows
    for row in rows:
        value = re.findall(r"\*\*(.+?)\*\*", row.split("|")[3])
        assert len(value) == 1 and value[0] in readme, (row[:60], value)


def test_the_checks_find_what_is_broken(tmp_path):
    """The checks themselves: a missing file, a missing heading and a missing docs path are found."""
    (tmp_path / "other.md").write_text("# A heading, with `code`\n\n```\n# not a heading\n```\n")
    assert anchors(tmp_path / "other.md") == {"a-heading-with-code"}
    text = "[x](other.md#a-heading-with-code) [y](gone.md) [z](other.md#not-a-heading) `[w](code.md)`"
    assert LINK.findall(prose(text)) == ["other.md#a-heading-with-code", "gone.md", "other.md#not-a-heading"]
    assert DOCS_PATH.findall("see docs/usage.md, docs/img/viewer.png and ../docs/x") == [
        "docs/usage.md",
        "docs/img/viewer.png",
    ]
