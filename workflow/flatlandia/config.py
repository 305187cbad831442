"""The workflow's settings: one schema holds every key's type, default and description.

Why one place: defaults that live in a YAML file, in ``.get`` fallbacks and in dataclass fields
drift apart, and a typo in a key is silently ignored. Here :func:`resolve` refuses unknown keys
(naming the closest valid one) and fills in the defaults, and :func:`settings` makes a section's
settings class (a dataclass whose fields, types and defaults are read from the schema, with a
strict ``from_dict``) so that no key is written out a second time. config/config.yaml and
config/README.md are generated views of the schema (:func:`render_config_yaml`,
:func:`render_readme`; ``flatlandia config --write``).
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import functools
import math
import operator
import textwrap
from pathlib import Path

#: the workflow's config schema: flatlandia/schemas/ in an installed wheel (pyproject.toml), else
#: workflow/schemas/ of the clone this package sits in
_IN_WHEEL = Path(__file__).resolve().parent / "schemas" / "config.schema.yaml"
SCHEMA_PATH = (
    _IN_WHEEL if _IN_WHEEL.is_file() else Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"
)


class ConfigError(ValueError):
    """A config key that does not exist or a value of the wrong kind; the message names the key."""


@functools.cache
def schema() -> dict:
    import yaml  # here, not at the top: a bundle of the benchmark's inputs carries the schema (no YAML reader)

    return yaml.safe_load(SCHEMA_PATH.read_text())


def _node(dotted: str) -> dict:
    """Schema node of a dotted section name ('' is the root)."""
    node = schema()
    for part in filter(None, dotted.split(".")):
        node = node["properties"][part]
    return node


def _defaults_of(node: dict):
    if "properties" in node and "default" not in node:
        return {k: _defaults_of(v) for k, v in node["properties"].items() if "default" in v or "properties" in v}
    return copy.deepcopy(node.get("default"))


def section_defaults(dotted: str = "") -> dict:
    """Every default under a section, nested as the config is: ``section_defaults('solver')``."""
    return _defaults_of(_node(dotted))


def _closest(key: str, known, prefix: str = "") -> str:
    """' (did you mean 'prefix.near'?)' for the closest known key, else the list of valid keys."""
    near = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    if near:
        return f" (did you mean '{_join(prefix, near[0])}'?)"
    return f"; valid keys under '{prefix or '(top level)'}': {', '.join(map(str, known))}"


def _join(prefix: str, key) -> str:
    return f"{prefix}.{key}" if prefix else str(key)


#: sections that moved: an old config naming them is told the new key (not only "did you mean")
MOVED = {"fine.geo": "solver"}
#: keys that are gone, and what took their place (an old config naming one stops with this)
REPLACED = {
    "solver.bearing_sigma_deg": "the fitted noise model in the solver's priors (without one: 'solver.default_bearing_sigma_deg')",
    "solver.log_range_sigma": "the fitted noise model times 'solver.msac_range_inflation' (without one: 'solver.default_log_range_sigma')",
    "solver.refine_log_range_sigma": "'solver.refine_range_inflation' (times the MSAC cost's range sigma)",
    "beyond.sequence.log_range_sigma": "the solver's noise model, as for single frames ('solver.msac_range_inflation')",
}


def _moved(dotted: str, value) -> list[str]:
    """The keys of a moved section as ``'old' (moved: now 'new')``, one per key given under it."""
    new = MOVED[dotted]
    keys = list(value) if isinstance(value, dict) and value else [None]
    return [
        f"'{_join(dotted, k) if k else dotted}' (moved: the section is now '{new}', e.g. '{_join(new, k or '...')}')"
        for k in keys
    ]


def unknown_keys(cfg, node: dict | None = None, prefix: str = "") -> list[str]:
    """Every key of ``cfg`` the schema does not know, as ``'a.b.c' (did you mean 'a.b.d'?)``, or
    for a section that moved (:data:`MOVED`) with its new name."""
    node = schema() if node is None else node
    each = node.get("additionalProperties")
    if isinstance(cfg, dict) and "properties" not in node and isinstance(each, dict):
        # a mapping of named entries of one shape (fine.train_overrides: a model -> its settings)
        names = node.get("propertyNames", {}).get("enum")
        out = []
        for key, value in cfg.items():
            if names is not None and key not in names:
                out.append(f"'{_join(prefix, key)}'{_closest(str(key), dict.fromkeys(names), prefix)}")
            else:
                out += unknown_keys(value, each, _join(prefix, key))
        return out
    if not isinstance(cfg, dict) or "properties" not in node:
        return []
    props = node["properties"]
    out = []
    for key, value in cfg.items():
        if _join(prefix, key) in MOVED:
            out += _moved(_join(prefix, key), value)
        elif _join(prefix, key) in REPLACED:
            out.append(f"'{_join(prefix, key)}' (replaced by {REPLACED[_join(prefix, key)]})")
        elif key in props:
            out += unknown_keys(value, props[key], _join(prefix, key))
        elif node.get("additionalProperties", True) is False:
            out.append(f"'{_join(prefix, key)}'{_closest(str(key), props, prefix)}")
    return out


def _merge(base, over):
    """``over`` on top of ``base``, recursively for dicts (lists and scalars replace)."""
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for key, value in over.items():
            out[key] = _merge(base.get(key), value) if key in base else copy.deepcopy(value)
        return out
    return copy.deepcopy(over)


def _types(node: dict) -> set:
    kind = node.get("type", [])
    return set([kind] if isinstance(kind, str) else kind)


def _coerce(value, node: dict):
    """Values of nested ``--config`` mappings reach the workflow as text ('12', 'true'): read text
    as YAML where the schema does not take a string and the text reads as another type."""
    if isinstance(value, dict):
        props = node.get("properties", {})
        extra = node.get("additionalProperties")
        return {k: _coerce(v, props.get(k, extra if isinstance(extra, dict) else {})) for k, v in value.items()}
    if isinstance(value, list) and isinstance(node.get("items"), dict):
        return [_coerce(v, node["items"]) for v in value]
    if isinstance(value, str) and _types(node) and "string" not in _types(node):
        from flatlandia.plumbing import validate
        from flatlandia.plumbing.errors import InputError

        try:  # the YAML door: no alias bomb, no key given twice
            parsed = validate.parse_yaml(value, "--config")
        except InputError:
            return value  # left as text: the type check names it
        return parsed if not isinstance(parsed, str) else value
    return value


def _type_errors(cfg: dict) -> list[str]:
    import jsonschema

    validator = jsonschema.Draft202012Validator(schema())
    errors = sorted(validator.iter_errors(cfg), key=lambda e: list(e.absolute_path))
    return [f"'{'.'.join(map(str, e.absolute_path)) or '(top level)'}': {_cut(e.message)}" for e in errors]


def _cut(message: str, limit: int = 300) -> str:
    """A jsonschema message quotes the whole value it refuses (a list of 100,000 values): its start."""
    return message if len(message) <= limit else f"{message[:limit]}... ({len(message):,} characters)"


def _non_finite(value, prefix: str = "") -> list[str]:
    """Every number that is NaN or infinite: JSON Schema's minimum/maximum let NaN through (every
    comparison with it is false), and no setting means anything at infinity."""
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in _non_finite(v, _join(prefix, k))]
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in _non_finite(v, f"{prefix}[{i}]")]
    if isinstance(value, float) and not math.isfinite(value):
        return [f"'{prefix}': {value} is not a finite number"]
    return []


#: settings that must agree with each other: (what, check, the keys named in the error)
SPLIT_KEYS = ("train", "val", "test")


def _cross_key_errors(full: dict) -> list[str]:
    """Checks JSON Schema cannot state: the split fractions share every query out exactly once."""
    split = full.get("split") or {}
    if all(isinstance(split.get(k), (int, float)) for k in SPLIT_KEYS):
        total = sum(float(split[k]) for k in SPLIT_KEYS)
        if math.isfinite(total) and abs(total - 1.0) > 1e-6:
            return [
                f"'split': train + val + test must sum to 1, not {total:g} "
                f"({', '.join(f'{k}={split[k]}' for k in SPLIT_KEYS)})"
            ]
    return []


def _bounded_shape(cfg: dict, validate) -> None:
    """Each value of ``cfg`` nests at most MAX_CONFIG_DEPTH deep and all of them, shared subtrees
    counted where each appears (YAML aliases: Snakemake's config keeps them shared), hold at most
    MAX_CONFIG_NODES values: measured in time linear in the distinct values
    (:func:`flatlandia.plumbing.validate.tree_shape`), so an alias bomb is refused in milliseconds."""
    limit, budget, total = validate.MAX_CONFIG_DEPTH, validate.MAX_CONFIG_NODES, 0
    for key, value in cfg.items():
        deep, size = validate.tree_shape(value, max_nodes=budget - total, max_depth=limit)
        name = str(key)[:80]
        if size == math.inf:
            raise ConfigError(f"'{name}': the value holds itself (a recursive YAML alias)")
        if deep > limit:
            raise ConfigError(f"'{name}': the value nests deeper than {limit} levels (MAX_CONFIG_DEPTH)")
        total += size
        if total > budget:
            raise ConfigError(
                f"'{name}': the config holds over {budget:,} values once its YAML aliases are expanded "
                "(MAX_CONFIG_NODES): an alias bomb?"
            )


def resolve(cfg: dict | None) -> dict:
    """The complete config: ``cfg`` over the schema's defaults, after refusing unknown keys,
    values of the wrong type, numbers that are not finite and settings that contradict each other.
    Raises :class:`ConfigError` listing every problem, as one line (a key's control characters
    escaped: the message names what a file gave)."""
    from flatlandia.plumbing import escape

    if cfg is not None and not isinstance(cfg, dict):
        raise ConfigError(f"the config must be a mapping of keys, not {type(cfg).__name__}")
    try:
        return _resolved(dict(cfg or {}))
    except ConfigError as e:
        raise ConfigError(escape.terminal(str(e))) from None


def _resolved(cfg: dict) -> dict:
    from flatlandia.plumbing import validate

    _bounded_shape(cfg, validate)  # before any of the walks below (a RecursionError is no message)
    unknown = unknown_keys(cfg)
    if unknown:
        raise ConfigError("unknown key " + "; unknown key ".join(unknown))
    full = _coerce(_merge(section_defaults(), cfg), schema())
    problems = _non_finite(full) or _type_errors(full) or _cross_key_errors(full)
    if problems:
        raise ConfigError("; ".join(problems))
    return full


# ----------------------------------------------------------------------------- settings classes

#: JSON Schema type -> Python type of a settings field (a list of types is their union)
_PY_TYPES = {
    "number": float,
    "integer": int,
    "boolean": bool,
    "string": str,
    "array": list,
    "object": dict,
    "null": type(None),
}

#: every settings class made by :func:`settings`, in the order their modules were imported
SETTINGS_CLASSES: list[type] = []


def _py_type(node: dict):
    kinds = [_PY_TYPES[k] for k in sorted(_types(node), key=list(_PY_TYPES).index)]
    return functools.reduce(operator.or_, kinds) if kinds else object


def _is_subsection(node: dict) -> bool:
    return "properties" in node and "default" not in node


def section_keys(dotted: str) -> list[str]:
    """The keys of a section that :func:`settings` makes fields of: its leaves (a key with a
    default), in schema order; nested sub-sections are left out (each gets a class of its own)."""
    return [k for k, v in _node(dotted).get("properties", {}).items() if not _is_subsection(v)]


def settings(dotted: str, *, frozen: bool = False):
    """Class decorator: the settings class of the config section ``dotted`` (e.g. ``"solver"``).

    The class becomes a dataclass (``frozen`` as asked, compared by value) whose fields are the
    section's keys (:func:`section_keys`), typed and defaulted from the schema, in schema order. The
    only fields written in the class body are *extras*: settings that a rule or a caller fixes and
    the schema does not hold (a model's name, a seed derived from the master seed); a body
    annotation naming a schema key is refused, so no key is written twice. The body keeps its
    methods (``__post_init__`` checks included). The class gets:

    - ``from_dict(d, **fixed)``: the schema defaults, ``d`` over them, then ``fixed``; a key that is
      not a field raises :class:`ConfigError` naming ``dotted.key`` and the closest field;
    - ``to_dict()``: every field (``dataclasses.asdict``), what checkpoints and tables store;
    - ``of(value)``: ``value`` itself when it is already one, else ``from_dict(value)``;
    - ``SECTION`` (``dotted``) and ``EXTRAS`` (the extras' names), read by tests/test_settings.py.
    """

    def build(cls):
        own = {k: v for k, v in cls.__dict__.get("__annotations__", {}).items() if "ClassVar" not in str(v)}
        twice = [k for k in own if k in _node(dotted).get("properties", {})]
        if twice:
            raise TypeError(
                f"{cls.__name__}: {', '.join(twice)} already {'is a key' if len(twice) == 1 else 'are keys'} "
                f"of the config section '{dotted}'; the class body declares only settings the schema lacks"
            )
        annotations = {}
        for key in section_keys(dotted):
            node = _node(dotted)["properties"][key]
            annotations[key] = _py_type(node)
            default = node.get("default")
            if isinstance(default, (dict, list)):
                setattr(cls, key, dataclasses.field(default_factory=functools.partial(copy.deepcopy, default)))
            else:
                setattr(cls, key, default)
        # extras first (what a rule fixes), then the schema's keys; class variables stay as they are
        cls.__annotations__ = {**cls.__dict__.get("__annotations__", {}), **annotations}
        for name, method in (("from_dict", _from_dict), ("to_dict", _to_dict), ("of", _of)):
            if name not in cls.__dict__:
                setattr(cls, name, method)
        out = dataclasses.dataclass(frozen=frozen)(cls)
        out.SECTION, out.EXTRAS = dotted, tuple(own)
        SETTINGS_CLASSES.append(out)
        return out

    return build


@classmethod
def _from_dict(cls, values: dict | None = None, **fixed):
    """The section's defaults, ``values`` over them, then ``fixed`` (settings a rule decides).
    Strict: a key that is not a setting raises ConfigError naming the closest one."""
    fields = [f.name for f in dataclasses.fields(cls)]
    given = {**dict(values or {}), **fixed}
    bad = [k for k in given if k not in fields]
    if bad:
        raise ConfigError(
            "unknown key "
            + "; unknown key ".join(f"'{_join(cls.SECTION, k)}'{_closest(str(k), fields, cls.SECTION)}" for k in bad)
        )
    return cls(**{k: copy.deepcopy(v) for k, v in given.items()})


def _to_dict(self) -> dict:
    """Every setting by name: JSON-ready when the values are (what checkpoints store)."""
    return dataclasses.asdict(self)


@classmethod
def _of(cls, value):
    """``value`` when it is already one of these settings, else :meth:`from_dict` of it (a dict or None)."""
    return value if isinstance(value, cls) else cls.from_dict(value)


# ----------------------------------------------------------------------------- generated views


def _leaves(node: dict, prefix: str = ""):
    """(dotted key, schema node) of every key that has a default, in schema order."""
    for key, child in node.get("properties", {}).items():
        name = _join(prefix, key)
        if "default" in child or "properties" not in child:
            yield name, child
        else:
            yield from _leaves(child, name)


def _yaml_value(value) -> str:
    """One value as YAML on one line (strings quoted only where YAML needs it)."""
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True, width=10_000).strip()
    return text.removesuffix("...").strip()


def _yaml_lines(node: dict, indent: int = 0) -> list[str]:
    pad = " " * indent
    lines = []
    for key, child in node.get("properties", {}).items():
        desc = " ".join(str(child.get("description", "")).split())
        wrapped = textwrap.wrap(desc, width=100 - indent - 2) if desc else []
        lines += [f"{pad}# {w}" for w in wrapped]
        if "properties" in child and "default" not in child:
            lines = (
                lines[: len(lines) - len(wrapped)] + ([""] if indent == 0 else []) + lines[len(lines) - len(wrapped) :]
            )
            lines.append(f"{pad}{key}:")
            lines += _yaml_lines(child, indent + 2)
        elif (
            isinstance(child.get("default"), dict)
            and child["default"]
            and isinstance(child.get("additionalProperties"), dict)
        ):
            lines.append(f"{pad}{key}:")  # a mapping of named entries: one line each, in schema order
            lines += [f"{pad}  {name}: {_yaml_value(entry)}" for name, entry in child["default"].items()]
        else:
            lines.append(f"{pad}{key}: {_yaml_value(child.get('default'))}")
    return lines


CONFIG_YAML_HEADER = """\
# The default run: every published scene of the scene sheet, with every setting at its default.
# GENERATED from workflow/schemas/config.schema.yaml by `flatlandia config --write`: do not edit.
# To change a setting, put only that key in a file of your own and pass it with
#   snakemake --cores 2 all --configfile my.yaml
# (config/paper.yaml is such a file); config/README.md lists every key.
"""


def render_config_yaml() -> str:
    return CONFIG_YAML_HEADER + "\n" + "\n".join(_yaml_lines(schema())) + "\n"


README_HEADER = """\
# Configuration

<!-- GENERATED from workflow/schemas/config.schema.yaml by `flatlandia config --write`: do not edit. -->

Every setting has its default and meaning in one place, `workflow/schemas/config.schema.yaml`;
`config/config.yaml` (the default run) and this page are generated from it. Change settings with
a file of your own holding only the keys you change, passed after the default:

    snakemake --cores 2 all --configfile my.yaml

Files given with `--configfile` are merged key by key, at every depth, over `config/config.yaml`
(see `config/paper.yaml`, the paper's training lengths). On the command line, a top-level key is
`--config seed=1`; a nested key is given as a YAML mapping of its section, which is merged the
same way (the section's other keys keep their values):

    snakemake --cores 2 all --config 'images={missing_gps: stop}' 'solver={top_k: 12}'

(Snakemake itself does not accept dotted keys such as `images.missing_gps=stop`.) A key the schema
does not know, or a value of the wrong type, stops the run before any job with one line naming
it, e.g.
`ERROR: config: unknown key 'solver.topk' (did you mean 'solver.top_k'?)`.
Relative paths are taken from the working directory, else from the repository. The scene sheet
(`scenes`) is checked against `workflow/schemas/scenes.schema.yaml`.

| key | default | meaning |
|---|---|---|
"""


def render_readme() -> str:
    rows = []
    for name, node in _leaves(schema()):
        desc = " ".join(str(node.get("description", "")).split()).replace("|", "\\|")
        rows.append(f"| `{name}` | `{_yaml_value(node.get('default'))}` | {desc} |")
    return README_HEADER + "\n".join(rows) + "\n"


def generated_files(repo: Path) -> dict[Path, str]:
    """The files generated from the schema, with the text they must hold."""
    return {repo / "config" / "config.yaml": render_config_yaml(), repo / "config" / "README.md": render_readme()}


def config_section(paths, section: str) -> dict:
    """One top-level section of layered YAML config files (later files update earlier ones, one
    level deep, as Snakemake's ``--configfile`` does); missing files are skipped. For benchmarks
    that read the workflow's config outside Snakemake."""
    from flatlandia.plumbing import validate

    out: dict = {}
    for p in map(Path, paths):
        if p.exists():
            for key, v in ((validate.read_config(p) or {}).get(section) or {}).items():
                out[key] = {**out.get(key, {}), **v} if isinstance(v, dict) else v
    return out
