"""The package's layout as docs/architecture.md tells it: at most 12 top-level modules, no module
named after a standard-library module, one meaning per module name, no files importing each other
in a loop and no import from a floor above (the rooms: top-level modules and subpackages), every
room named in docs/architecture.md. Fast: it reads the source, imports nothing of it."""

from __future__ import annotations

import ast
import re
import sys
from collections import defaultdict
from pathlib import Path

import networkx as nx

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "workflow" / "flatlandia"
ARCHITECTURE = (REPO / "docs" / "architecture.md").read_text()


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The package's modules ``name`` imports anywhere in its file (function bodies and
    TYPE_CHECKING blocks too: a loop through them is still a loop to a reader)."""
    found = set()
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                )
            # ``from pkg import module`` imports the module; ``from module import name``, the module
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in MODULES:
                t = t.rsplit(".", 1)[0] if "." in t else ""
            if t and t != name and t != "flatlandia":
                found.add(t)
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _room(module: str) -> str:
    """A top-level module or subpackage: the rooms the layout is drawn in."""
    parts = module.split(".")
    return ".".join(parts[:2])


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node: the loops."""
    g = nx.DiGraph((a, b) for a, targets in graph.items() for b in targets)
    return [sorted(c) for c in nx.strongly_connected_components(g) if len(c) > 1]


def test_no_files_import_each_other_in_a_loop():
    assert _cycles(GRAPH) == [], "modules that import each other in a loop"


def test_no_room_imports_from_a_floor_above_its_own():
    """The rooms (top-level modules, subpackages) form layers: a loop between two rooms means one
    of them imports from a floor above its own."""
    rooms: dict[str, set[str]] = defaultdict(set)
    why: dict[tuple[str, str], list[str]] = defaultdict(list)
    for m, targets in GRAPH.items():
        for t in targets:
            a, b = _room(m), _room(t)
            if a != b:
                rooms[a].add(b)
                why[(a, b)].append(f"{m} -> {t}")
    loops = _cycles(dict(rooms))
    detail = [(a, b, why[(a, b)][:3]) for loop in loops for a in loop for b in loop if (a, b) in why]
    assert loops == [], detail


def test_at_most_twelve_top_level_modules_and_none_named_after_the_standard_library():
    top = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__")
    assert len(top) <= 12, top
    clashes = [
        m.rsplit(".", 1)[-1] for m in MODULES if m.count(".") >= 1 and m.rsplit(".", 1)[-1] in sys.stdlib_module_names
    ]
    assert clashes == [], f"modules named after standard-library modules: {clashes}"


#: the one job every stage has, named alike in each stage's subpackage: its evaluation (the
#: stage's errors and summaries) and its training (the stage's models)
STAGE_ROLES = {"evaluation", "training"}


def test_one_meaning_per_module_name():
    """No two modules of the same name in different subpackages doing different jobs: a name is
    used once, or it is a role every stage has (:data:`STAGE_ROLES`)."""
    by_name = defaultdict(list)
    for m, path in MODULES.items():
        if path.name != "__init__.py":
            by_name[m.rsplit(".", 1)[-1]].append(m)
    assert {k: v for k, v in by_name.items() if len(v) > 1 and k not in STAGE_ROLES} == {}


def test_the_layers_of_entry_points_are_named_apart():
    """The solver, the city search and the user's localizer each have their own verb."""
    defined = defaultdict(list)
    for m, path in MODULES.items():
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name in {"localize", "localize_sequence"}:
                defined[node.name].append(m)
    assert defined == {"localize": ["flatlandia.localize.solve"], "localize_sequence": ["flatlandia.localize.solve"]}


def test_docs_architecture_names_every_room():
    rooms = sorted({_room(m) for m in MODULES if m != "flatlandia"})
    missing = [r for r in rooms if not re.search(rf"`{re.escape(r.split('.', 1)[1])}/?`", ARCHITECTURE)]
    assert missing == [], f"docs/architecture.md does not name: {missing}"
    subpackages = sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py"))
    for sub in subpackages:  # and every module of each subpackage, in its row
        for path in sorted((PACKAGE / sub).glob("*.py")):
            if path.stem != "__init__":
                assert f"`{path.stem}`" in ARCHITECTURE, f"docs/architecture.md does not name {sub}/{path.stem}"


def _flatlandia_imports(tree: ast.AST) -> list[ast.alias]:
    """The names a file imports from the flatlandia package."""
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("flatlandia"):
            out += n.names
        elif isinstance(n, ast.Import):
            out += [a for a in n.names if a.name.startswith("flatlandia")]
    return out


def test_no_rule_script_shadows_a_module_it_imports():
    """A rule script that binds a name it imported from flatlandia (``models = {}`` beside ``from
    flatlandia.fine import models``) reads the wrong object at its first use after the binding; a
    lint fix then drops the "unused" import, and only a full run finds it (the images scene's
    scene_localization did so once)."""
    shadowed = []
    for path in sorted((REPO / "workflow" / "scripts").glob("*.py")):
        tree = ast.parse(path.read_text())
        imported = {(a.asname or a.name).split(".")[0] for a in _flatlandia_imports(tree)}
        bound = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
        bound |= {n.arg for n in ast.walk(tree) if isinstance(n, ast.arg)}
        shadowed += [f"{path.name}: {name}" for name in sorted(imported & bound)]
    assert shadowed == []


LOCALIZE = PACKAGE / "localize"
#: the module that reads a map and picks its kind (``flatlandia.localize.maps.load_map``, ``KINDS``):
#: the one place of localize/ a map's kind is chosen
MAP_READER = LOCALIZE / "maps.py"


def _map_kinds() -> tuple[set[str], set[str]]:
    """(the kinds' names, the kinds' classes): each class of localize/ that sets ``kind = "..."``."""
    names, classes = set(), set()
    for path in LOCALIZE.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ClassDef):
                continue
            for stmt in node.body:
                if (
                    isinstance(stmt, ast.Assign)
                    and [getattr(t, "id", None) for t in stmt.targets] == ["kind"]
                    and isinstance(stmt.value, ast.Constant)
                    and isinstance(stmt.value.value, str)
                ):
                    names.add(stmt.value.value)
                    classes.add(node.name)
    return names, classes


def _strings(node: ast.AST) -> set[str]:
    """The string constants of an operand (a literal, or a tuple, list or set of them)."""
    items = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
    return {n.value for n in items if isinstance(n, ast.Constant) and isinstance(n.value, str)}


def test_no_module_of_localize_branches_on_a_maps_kind():
    """A map's kind is its class (issue 46): behaviour comes from the class's methods, chosen once
    in the reader (localize/maps.py). Elsewhere in localize/ no comparison of a ``kind`` with a
    kind's name (``m.kind == "city"``) and no ``isinstance`` of a kind's class: adding a kind is its
    class and its line in the reader's ``KINDS``, not a hunt through the localizer."""
    names, classes = _map_kinds()
    assert {"scene", "city"} <= names and {"SceneMap", "CityMap"} <= classes
    branches = []
    for path in sorted(LOCALIZE.glob("*.py")):
        if path == MAP_READER:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                operands = [node.left, *node.comparators]
                kind = any(getattr(o, "attr", getattr(o, "id", None)) == "kind" for o in operands)
                if kind and set().union(*map(_strings, operands)) & names:
                    branches.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
            elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and len(node.args) == 2:
                kinds = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
                if {getattr(k, "attr", getattr(k, "id", None)) for k in kinds} & classes:
                    branches.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert branches == [], f"branches on a map's kind outside the reader (give the kinds' classes a method): {branches}"


#: a function longer than this says why in its docstring ("Over 100 lines: ...")
MAX_FUNCTION_LINES = 100


def test_no_function_over_100_lines_without_a_reason_in_its_docstring():
    long = []
    for m, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES and "Over 100 lines:" not in (ast.get_docstring(node) or ""):
                    long.append(f"{m}.{node.name}: {lines} lines")
    assert long == [], long
