"""Every dotted name of the package that the docs and the docstrings give (``flatlandia.x.y``) names
something that exists: a module, or an attribute of one (a renamed function leaves no stale pointer)."""

from __future__ import annotations

import ast
import importlib
import re

import pytest
from conftest import REPO

NAME = re.compile(r"(?<![/\w.-])flatlandia(?:\.[A-Za-z_]\w*)+")
#: what looks like a dotted name but is a file (flatlandia.json of the authors' schema, ...)
FILE_SUFFIXES = {"json", "yaml", "yml", "md", "py", "tsv", "zip", "parquet", "csv", "egg", "toml", "log"}


def resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def doc_names() -> dict[str, str]:
    """Every dotted name in README.md, docs/*.md and the package's docstrings -> where it first is."""
    found: dict[str, str] = {}
    texts = [(p, p.read_text()) for p in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]]
    for p in sorted((REPO / "workflow" / "flatlandia").rglob("*.py")):
        tree = ast.parse(p.read_text())
        docs = [
            ast.get_docstring(n) for n in ast.walk(tree) if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef))
        ]
        texts.append((p, "\n".join(d for d in docs if d)))
    for p, text in texts:
        for m in NAME.finditer(text):
            name = m.group(0).rstrip(".")
            if name.rsplit(".", 1)[-1] in FILE_SUFFIXES:
                continue
            found.setdefault(name, str(p.relative_to(REPO)))
    return found


def test_every_dotted_name_in_the_docs_and_docstrings_resolves():
    names = doc_names()
    assert len(names) > 50
    stale = {n: where for n, where in names.items() if not resolves(n)}
    assert not stale, "\n".join(f"{where}: {n}" for n, where in sorted(stale.items(), key=lambda kv: kv[1]))


@pytest.mark.parametrize("name", ["flatlandia.solver.noise.NoiseModel", "flatlandia.proposals.for_queries"])
def test_the_resolver_finds_real_names(name):
    assert resolves(name) and not resolves(name + "_renamed")
