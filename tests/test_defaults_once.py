"""Every default once: a setting's default lives in the schema (workflow/schemas/config.schema.yaml)
and nowhere else. Code that needs it reads it from there (``config.section_defaults``, a settings
class) or takes no default, so that the rule passes the config's value.

What is checked mechanically, in every module of the package and every rule script (their syntax
trees) and in the rules (line by line): a literal equal to a schema key's default where the name
says it is that key, i.e.

- a function parameter's default (``min_points: int = 2`` beside ``images.min_points: 2``),
- a module constant or class field (``MIN_POINTS = 2``, ``scale_m: float = 50.0``),
- ``mapping.get("key", literal)``, and an argparse option's ``default=`` (``--key-name``),
- a rule's keyword (``key=literal``),

plus any literal equal to a distinctive text default (a URL, a path). Not flagged: empty values
(``""``, None, ``[]``, ``{}``: nothing chosen) and a list holding every value of the key's enum (the
vocabulary itself, e.g. the map types, whose home is another matter than defaults). Exceptions
that are not a restatement go into :data:`ALLOWED`, each with why.
"""

from __future__ import annotations

import ast
import math
import re
import textwrap

import pytest
from conftest import REPO

from flatlandia import config

PACKAGE = REPO / "workflow" / "flatlandia"
SCRIPTS = REPO / "workflow" / "scripts"
RULES = [*sorted((REPO / "workflow" / "rules").rglob("*.smk")), REPO / "workflow" / "Snakefile", REPO / "Snakefile"]

#: (module relative to workflow/flatlandia, or "*" for any; name) -> why it is not a restated default
ALLOWED = {
    ("*", "seed"): "a random step's seed parameter: any value is as good as another, so its 0 chooses "
    "nothing; the rules pass the config's seed (the master seed, or seed + coarse.seed_offset)",
    ("*", "split"): "a query split's name: 'test' is the benchmark's held-out split, which scoring and "
    "the evaluations read unless told otherwise; not the settings city.split / sequences.split, which "
    "choose the split those two stages localize",
    ("geo.py", "MIN_OBJECTS"): "the floor of objects a pose is found and checked with (a fact of the "
    "geometry, not a choice): images.min_objects may not go below it (the schema's minimum, "
    "test_the_floor_of_objects_is_the_schema_minimum) and defaults to it",
    ("sequences/evaluation.py", "camera_prior"): "a row of the beyond table with the camera prior on or off "
    "(sequences.scene_camera_prior lists the rows), not the solver's setting solver.camera_prior",
}

#: text defaults this long are distinctive: the same text anywhere is a restatement (a URL, a path)
DISTINCTIVE_CHARS = 12


def _schema_keys() -> dict[str, list[tuple[str, object, list | None]]]:
    """Leaf name -> [(dotted key, default, the enum of its items or values)] of every schema key with a default."""
    out: dict[str, list] = {}
    for dotted, node in config._leaves(config.schema()):
        if "default" not in node:
            continue
        enum = node.get("enum") or (node.get("items") or {}).get("enum")
        out.setdefault(dotted.rsplit(".", 1)[-1], []).append((dotted, node["default"], enum))
    return out


KEYS = _schema_keys()
DISTINCTIVE = {
    d: dotted
    for entries in KEYS.values()
    for dotted, d, _ in entries
    if isinstance(d, str) and len(d) >= DISTINCTIVE_CHARS
}


def _same(a, b) -> bool:
    """Equal as config values: 3 == 3.0, but True is not 1 and [1] is [1.0]."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b), rel_tol=0, abs_tol=0)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return type(a) is type(b) and a == b


def _empty(value) -> bool:
    return value is None or (isinstance(value, (str, list, tuple, dict)) and len(value) == 0)


def restated(name: str, value) -> list[str]:
    """The schema keys named ``name`` (any case, leading underscores dropped) whose default ``value`` is."""
    if _empty(value):
        return []
    out = []
    for dotted, default, enum in KEYS.get(name.lower().lstrip("_"), ()):
        if enum and isinstance(value, (list, tuple)) and sorted(map(str, value)) == sorted(map(str, enum)):
            continue  # every value there is: the vocabulary, not a choice
        if _same(value, default):
            out.append(dotted)
    return out


def _literal(node):
    try:
        return ast.literal_eval(node), True
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return None, False


def findings(source: str) -> list[tuple[int, str, str, str]]:
    """(line, what, name, schema key) of every restated default in a module's source."""
    out: list[tuple[int, str, str, str]] = []

    def check(line, what, name, value_node):
        value, ok = _literal(value_node)
        if ok:
            out.extend((line, what, name, k) for k in restated(name, value))

    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = node.args
            positional = a.posonlyargs + a.args
            for arg, d in zip(positional[len(positional) - len(a.defaults) :], a.defaults):
                check(d.lineno, "parameter default", arg.arg, d)
            for arg, d in zip(a.kwonlyargs, a.kw_defaults):
                if d is not None:
                    check(d.lineno, "parameter default", arg.arg, d)
        elif isinstance(node, ast.Assign):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    check(node.lineno, "constant", target.id, node.value)
                elif isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                    for t, v in zip(target.elts, node.value.elts):
                        if isinstance(t, ast.Name):
                            check(node.lineno, "constant", t.id, v)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None:
            check(node.lineno, "field default", node.target.id, node.value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            first = node.args[0] if node.args else None
            key = first.value if isinstance(first, ast.Constant) and isinstance(first.value, str) else None
            if node.func.attr in ("get", "setdefault", "pop") and key and len(node.args) == 2:
                check(node.lineno, f".{node.func.attr}() fallback", key, node.args[1])
            if node.func.attr == "add_argument" and key and key.startswith("--"):
                for kw in node.keywords:
                    value, ok = _literal(kw.value) if kw.arg == "default" else (None, False)
                    name = key[2:].replace("-", "_")
                    if ok and not _empty(value):  # argparse defaults are often the text of the value
                        hits = restated(name, value) or [d for d, dv, _ in KEYS.get(name, ()) if str(dv) == str(value)]
                        out.extend((node.lineno, "argparse default", key, k) for k in hits)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in DISTINCTIVE:
            out.append((node.lineno, "text", repr(node.value), DISTINCTIVE[node.value]))
    return out


def _allowed(module: str, name: str) -> bool:
    name = name.lstrip("-").replace("-", "_")
    return any((m in ("*", module)) and n.lower() == name.lower() for m, n in ALLOWED)


def _package_findings() -> list[tuple[str, int, str, str, str]]:
    out = []
    for path in [*sorted(PACKAGE.rglob("*.py")), *sorted(SCRIPTS.glob("*.py"))]:
        module = (
            path.relative_to(PACKAGE).as_posix() if path.is_relative_to(PACKAGE) else path.relative_to(REPO).as_posix()
        )
        out += [(module, *f) for f in findings(path.read_text())]
    return out


def _message(found) -> str:
    lines = [
        f"{module}:{line}: {what} {name} restates the schema's default of `{key}` ({config._node(key)['default']!r})"
        for module, line, what, name, key in found
    ]
    return (
        "a setting's default is written again outside workflow/schemas/config.schema.yaml:\n  "
        + "\n  ".join(lines)
        + "\nRead it from the schema (`config.section_defaults(section)[key]`, as images/image_audit.py "
        "does, or the section's settings class), or take no default so that the rule passes the config's "
        "value. A name that only looks like the key goes into ALLOWED in tests/test_defaults_once.py, with why."
    )


def test_no_schema_default_is_restated_in_the_package():
    found = [f for f in _package_findings() if not _allowed(f[0], f[3])]
    assert not found, _message(found)


#: a rule's keyword given a value: ``min_points=2,`` (params, resources, a function's arguments)
RULE_KEYWORD = re.compile(r"\b([A-Za-z_]\w*)\s*=\s*([^=,()]+?)\s*(?=,|\)|$)")


def rule_findings(text: str) -> list[tuple[int, str, str, str]]:
    """(line, what, name, schema key) of every ``key=literal`` of a rule file whose literal is the
    key's default, and of every distinctive text default written in it."""
    out = []
    for number, line in enumerate(text.splitlines(), 1):
        for m in RULE_KEYWORD.finditer(line):
            try:
                value = ast.literal_eval(m.group(2).strip())
            except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
                continue
            out += [(number, "rule keyword", m.group(1), k) for k in restated(m.group(1), value)]
        out += [(number, "text", repr(d), k) for d, k in DISTINCTIVE.items() if f'"{d}"' in line or f"'{d}'" in line]
    return out


def test_no_schema_default_is_restated_in_the_rules():
    found = [(p.relative_to(REPO).as_posix(), *f) for p in RULES for f in rule_findings(p.read_text())]
    assert not found, _message(found)


def test_every_allowed_exception_is_still_needed():
    """An entry of ALLOWED that matches nothing any more is removed (the list stays short and true)."""
    found = _package_findings()
    stale = [
        (module, name)
        for module, name in ALLOWED
        if not any(module in ("*", f[0]) and name.lower() == f[3].lstrip("-").replace("-", "_").lower() for f in found)
    ]
    assert not stale, f"ALLOWED entries that match nothing: {stale}"


SOURCE_WITH_EVERY_KIND = """
import argparse

MIN_POINTS = 2
URL = "https://codeload.github.com/IIT-PAVIS/Flatlandia/zip/refs/heads/main"


class Graph:
    scale_m: float = 50.0


def queries(views, min_objects: int = 3, *, tol_m=0.1):
    return cfg.get("threshold_m", 15.0)


def cli():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dilate-px", default="0")


ok = lambda radius_m=30.0: radius_m
"""


def test_the_check_finds_each_kind_of_restatement():
    """The check itself on a module written to hold one restatement of each kind (and none else)."""
    got = {(what, name, key) for _, what, name, key in findings(textwrap.dedent(SOURCE_WITH_EVERY_KIND))}
    assert ("constant", "MIN_POINTS", "images.min_points") in got
    assert ("text", repr(config.section_defaults("fetch")["url"]), "fetch.url") in got
    assert ("field default", "scale_m", "coarse.train.scale_m") in got
    assert ("parameter default", "min_objects", "images.min_objects") in got
    assert ("parameter default", "tol_m", "recover.tol_m") in got
    assert (".get() fallback", "threshold_m", "images.align.threshold_m") in got
    assert ("argparse default", "--dilate-px", "segment.dilate_px") in got
    assert ("parameter default", "radius_m", "coarse.train.radius_m") in got
    # a value other than the default, an empty one, the whole vocabulary: not restatements
    assert not findings("def f(min_points=5, sha256='', map_types=('gt', 'depth')):\n    pass\n")
    assert not findings("def f(seed):\n    return seed\n")  # no default at all
    assert rule_findings('        min_points=2,\n        min_objects=config["images"]["min_objects"],\n') == [
        (1, "rule keyword", "min_points", "images.min_points")
    ]


def test_the_floor_of_objects_is_the_schema_minimum():
    """images.min_objects may not go below the geometry's floor (geo.MIN_OBJECTS), and localize,
    the published local maps and the fine stage's solvability use that one floor."""
    import inspect

    from flatlandia import geo, localize
    from flatlandia.benchmark import metrics
    from flatlandia.data import published

    node = config.schema()["properties"]["images"]["properties"]["min_objects"]
    assert node["minimum"] == geo.MIN_OBJECTS <= node["default"]
    assert localize.MIN_OBJECTS == geo.MIN_OBJECTS
    assert inspect.signature(published.read_local_maps).parameters["min_objects"].default == geo.MIN_OBJECTS
    assert inspect.signature(metrics.solvable).parameters["min_objects"].default == geo.MIN_OBJECTS


def test_a_users_sequence_gets_the_simulated_sequences_noise_floor():
    """A companion frame that did not move gets the odometry floor of the simulated sequences
    (flatlandia.sequences.MIN_SIGMA_M), not a second copy of it."""
    import numpy as np

    from flatlandia import localize, sequences
    from flatlandia.sequences import protocol

    xy, cls = np.array([[5.0, 1.0], [7.0, -2.0], [9.0, 0.5]]), np.array([1, 2, 3])
    frame = localize.query_json(xy, cls)
    seq = localize.parse_sequence({"frames": [frame, {**frame, "pose": {"x": 0.0, "y": 0.0, "theta_deg": 0.0}}]})
    assert seq.sigma[1, 0] == sequences.MIN_SIGMA_M == protocol.MIN_SIGMA_M
    assert protocol.MIN_SIGMA_DEG == sequences.MIN_SIGMA_DEG


def test_the_cli_says_the_librarys_number_of_alternatives(capsys):
    from flatlandia import cli, localize

    with pytest.raises(SystemExit):
        cli.main(["localize", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"next-best distinct poses (default {localize.ALTERNATIVES})" in help_text
