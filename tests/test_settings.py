"""Every settings class is its config section: fields = the section's keys + the class's declared
extras, defaults = the schema's, and ``from_dict`` refuses an unknown key naming the closest one."""

from __future__ import annotations

import dataclasses
import importlib
import json

import pytest

from flatlandia import config

#: every settings class of the workflow: module, class -> (config section, frozen); a class made
#: with ``config.settings`` and missing here fails test_every_settings_class_is_listed
EXPECTED = {
    ("flatlandia.solver.settings", "SolverConfig"): ("solver", False),
    ("flatlandia.coarse.solver_proposals", "SolverProposalConfig"): ("coarse.solver", True),
    ("flatlandia.coarse.target", "SimilarityConfig"): ("coarse.similarity", True),
    ("flatlandia.coarse.retrieval", "CoarseTrainConfig"): ("coarse.train", False),
    ("flatlandia.city.search", "SearchConfig"): ("city.search", False),
    ("flatlandia.objects.clustering", "ClusterParams"): ("objects.cluster", True),
    ("flatlandia.objects.principal_plane", "PlaneConfig"): ("objects.principal_plane", True),
    ("flatlandia.fine.models", "FineTrainConfig"): ("fine.train", False),
    ("flatlandia.data.fetch", "Limits"): ("fetch", True),
    ("flatlandia.images.sfm", "SfmOptions"): ("sfm", False),
    ("flatlandia.solver.sequence", "SequenceConfig"): ("beyond.sequence", False),
}

#: the settings that the checkpoints written before the settings classes stored (``to_dict`` at
#: the defaults); such a checkpoint must still load, to the same settings
STORED = {
    "CoarseTrainConfig": {
        "loss": "simtrip", "epochs": 20, "batch_size": 20, "lr": 0.01, "weight_decay": 0.0, "margin": 0.5,
        "trip_weight": 1.0, "hard_negatives": 0.5, "sim_weight_floor": 0.1, "grad_clip": 1.0, "lr_schedule": "cosine",
        "lr_min_factor": 0.01, "hidden": 32, "heads": 2, "layers": 3, "out_dim": 32, "dropout": 0.0, "normalize": True,
        "conv": "gatv2", "train_maps": ["gt", "depth"], "batching": "scene", "eval_every": 1, "seed": 0, "scale_m": 50.0,
        "depth_unit_m": None, "knn": 7, "radius_m": 30.0, "bb_enlarge": 0.1,
    },
    "FineTrainConfig": {
        "model": "MLP", "map_type": "depth", "hidden": 64, "heads": 4, "rounds": 3, "knn": 3, "epochs": 100,
        "batch_size": 32, "lr": 0.002, "weight_decay": 0.0, "lr_schedule": "none", "scale_m": 15.0, "depth_unit_m": 25.0,
        "angle_weight": 1.0, "augment": False, "aug_rotate_deg": 180.0, "aug_translate": 0.25, "aug_depth_scale": 0.2,
        "seed": 0, "eval_every": 2, "extra": {},
    },
}  # fmt: skip


def _classes() -> dict[str, type]:
    for module, _ in EXPECTED:
        importlib.import_module(module)
    return {c.__name__: c for c in config.SETTINGS_CLASSES if c.__module__.startswith("flatlandia.")}


CLASSES = _classes()


def test_every_settings_class_is_listed():
    found = {(c.__module__, c.__name__) for c in CLASSES.values()}
    assert found == set(EXPECTED)
    for (_, name), (section, frozen) in EXPECTED.items():
        cls = CLASSES[name]
        assert cls.SECTION == section
        assert cls.__dataclass_params__.frozen is frozen  # hashing and equality as the code relies on


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_fields_are_the_section_keys_plus_the_declared_extras(name):
    cls = CLASSES[name]
    fields = [f.name for f in dataclasses.fields(cls)]
    keys = config.section_keys(cls.SECTION)
    assert len(fields) == len(set(fields))
    assert sorted(fields) == sorted([*keys, *cls.EXTRAS])
    assert not set(cls.EXTRAS) & set(keys)
    sub = {k for k, v in config.section_defaults(cls.SECTION).items() if k not in keys}
    assert not sub & set(fields)  # nested sub-sections are classes of their own


def _fits(value, kind) -> bool:
    """The value fits the field's type (an integer is a number)."""
    kinds = getattr(kind, "__args__", (kind,))
    return value is None and type(None) in kinds or isinstance(value, kinds) or float in kinds and type(value) is int


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_defaults_are_the_schema_defaults(name):
    cls = CLASSES[name]
    defaults = config.section_defaults(cls.SECTION)
    made = cls().to_dict()
    for key in config.section_keys(cls.SECTION):
        assert made[key] == defaults[key] and type(made[key]) is type(defaults[key]), key
    types = {f.name: f.type for f in dataclasses.fields(cls)}
    assert all(_fits(made[k], types[k]) for k in config.section_keys(cls.SECTION))
    assert cls.from_dict(None) == cls() == cls.from_dict(json.loads(json.dumps(cls().to_dict())))
    assert cls.of(None) == cls() and cls.of(made) == cls()


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_the_default_config_gives_the_defaults(name):
    cls = CLASSES[name]
    section = config.resolve({})
    for part in cls.SECTION.split("."):
        section = section[part]
    leaves = {k: v for k, v in section.items() if k in config.section_keys(cls.SECTION)}
    assert cls.from_dict(leaves) == cls()


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_an_unknown_key_is_refused_naming_the_closest(name):
    cls = CLASSES[name]
    fields = [f.name for f in dataclasses.fields(cls)]
    for key in fields:
        typo = key + "x"
        with pytest.raises(config.ConfigError) as err:
            cls.from_dict({typo: 1})
        assert str(err.value) == f"unknown key '{cls.SECTION}.{typo}' (did you mean '{cls.SECTION}.{key}'?)"
    with pytest.raises(config.ConfigError, match=f"unknown key '{cls.SECTION}.zzz'; valid keys under"):
        cls.from_dict({}, zzz=1)


@pytest.mark.parametrize("name", sorted(STORED))
def test_the_settings_stored_in_checkpoints_read_back_unchanged(name):
    cls = CLASSES[name]
    stored = STORED[name]
    assert cls.from_dict(stored).to_dict() == stored == cls().to_dict()
    assert json.loads(json.dumps(cls().to_dict())) == stored
