"""The config schema is the one source of settings: strict keys, defaults, generated files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from flatlandia import cli, config

REPO = Path(__file__).resolve().parents[1]


def test_generated_config_files_are_in_sync():
    for path, text in config.generated_files(REPO).items():
        assert path.read_text() == text, f"{path} is stale: run `flatlandia config --write`"
    assert cli.main(["config", "--repo", str(REPO)]) == 0


def test_config_yaml_is_the_schema_defaults():
    loaded = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    assert loaded == config.section_defaults()
    assert config.resolve(loaded) == loaded


def test_every_key_has_a_default_and_a_description():
    def walk(node, name=""):
        for key, child in node.get("properties", {}).items():
            dotted = f"{name}.{key}" if name else key
            assert child.get("description") or "properties" in child, f"{dotted}: no description"
            if "properties" in child and "default" not in child:
                assert child.get("additionalProperties") is False, f"{dotted}: unknown keys must be refused"
                walk(child, dotted)
            else:
                assert "default" in child, f"{dotted}: no default"

    assert config.schema().get("additionalProperties") is False
    walk(config.schema())


@pytest.mark.parametrize(
    "cfg, message",
    [
        ({"solver": {"topk": 3}}, "unknown key 'solver.topk' (did you mean 'solver.top_k'?)"),
        (
            {"fine": {"geo": {"top_k": 3}}},
            "unknown key 'fine.geo.top_k' (moved: the section is now 'solver', e.g. 'solver.top_k')",
        ),
        ({"sfm": {"matchr": "sequential"}}, "unknown key 'sfm.matchr' (did you mean 'sfm.matcher'?)"),
        ({"selct": [1]}, "unknown key 'selct' (did you mean 'select'?)"),
        ({"fine": {"train_overrides": {"gat": {"epoch": 3}}}}, "'fine.train_overrides.gat.epoch'"),
        ({"solver": {"top_k": "six"}}, "'solver.top_k': 'six' is not of type 'integer'"),
        ({"sfm": {"matcher": "fast"}}, "'sfm.matcher': 'fast' is not one of"),
    ],
)
def test_typos_and_wrong_types_are_refused_with_the_key_named(cfg, message):
    with pytest.raises(config.ConfigError) as err:
        config.resolve(cfg)
    assert message in str(err.value)


def test_resolve_fills_defaults_under_a_partial_section():
    full = config.resolve({"solver": {"top_k": 3}})
    assert full["solver"]["top_k"] == 3
    assert full["solver"]["max_pairs"] == config.section_defaults("solver")["max_pairs"]
    assert full["fine"]["train"]["epochs"] == config.section_defaults("fine.train")["epochs"]
    assert full["objects"]["cluster"]["split_extent_m"] is None


def _toy(dotted: str = "solver", **kwargs):
    """A settings class made for a test, left out of the registry tests/test_settings.py walks."""

    def make(cls):
        made = config.settings(dotted, **kwargs)(cls)
        config.SETTINGS_CLASSES.remove(made)
        return made

    return make


def test_settings_classes_take_fields_types_and_defaults_from_the_schema():
    @_toy()
    class Toy:
        """A toy."""

        model: str = "x"

        def doubled(self) -> int:
            return 2 * self.top_k

    defaults = config.section_defaults("solver")
    names = [f.name for f in dataclasses.fields(Toy)]
    assert names == ["model", *defaults]  # the extras first, then the schema's keys in schema order
    assert Toy.SECTION == "solver" and Toy.EXTRAS == ("model",) and Toy.__doc__ == "A toy."
    toy = Toy.from_dict({"top_k": 3}, model="mlp")
    assert (toy.top_k, toy.model, toy.max_pairs, toy.doubled()) == (3, "mlp", defaults["max_pairs"], 6)
    assert Toy().to_dict() == {"model": "x", **defaults}
    assert Toy.from_dict(None) == Toy() == Toy.from_dict(Toy().to_dict())
    assert Toy.of(toy) is toy and Toy.of({"top_k": 3}) == Toy(top_k=3) and Toy.of(None) == Toy()
    types = {f.name: f.type for f in dataclasses.fields(Toy)}
    assert (types["top_k"], types["tau"], types["covis_metric"]) == (int, float, bool)
    with pytest.raises(config.ConfigError, match="'solver.top_kk' \\(did you mean 'solver.top_k'\\?\\)"):
        Toy.from_dict({"top_kk": 1})
    with pytest.raises(config.ConfigError, match="'solver.modle' \\(did you mean 'solver.model'\\?\\)"):
        Toy.from_dict({}, modle="mlp")


def test_settings_fields_hold_copies_of_mutable_defaults_and_leave_out_sub_sections():
    @_toy("objects", frozen=True)
    class Objects:
        pass

    assert [f.name for f in dataclasses.fields(Objects)] == ["audit_radius_m"]  # cluster, principal_plane: own classes
    with pytest.raises(dataclasses.FrozenInstanceError):
        Objects().audit_radius_m = 1.0

    @_toy("objects.cluster")
    class Cluster:
        pass

    a, b = Cluster(), Cluster()
    a.eps_m_by_class["pole"] = 9.0
    assert b.eps_m_by_class == config.section_defaults("objects.cluster")["eps_m_by_class"]
    assert {f.name: f.type for f in dataclasses.fields(Cluster)}["split_extent_m"] == float | None


def test_a_settings_class_cannot_declare_a_schema_key_again():
    with pytest.raises(TypeError, match="top_k already is a key of the config section 'solver'"):

        @_toy()
        class Twice:
            top_k: int = 6


@pytest.mark.slow  # the published data (flat_root)
def test_a_typo_in_a_config_file_stops_the_run_before_any_job(repo, flat_root, tmp_path):
    from snakemake_runner import smk

    mine = tmp_path / "my.yaml"
    mine.write_text("solver:\n  topk: 3\n")
    res = smk(repo, tmp_path, "-n", "all", "--configfile", str(mine), "--config", f"flatlandia_root={flat_root}")
    assert res.returncode != 0
    err = res.stderr.strip().splitlines()
    assert err[-1] == "ERROR: config: unknown key 'solver.topk' (did you mean 'solver.top_k'?)"
    assert "Traceback" not in res.stderr and "Building DAG" not in res.stdout + res.stderr
    assert not (tmp_path / "results").exists()


@pytest.mark.slow  # the published data (flat_root)
def test_nested_command_line_overrides_merge_deeply(repo, flat_root, tmp_path):
    """`--config 'section={key: value}'` changes that key only; a bad value names the allowed ones."""
    from snakemake_runner import smk

    out = tmp_path / "resolved.yaml"
    (tmp_path / "config").symlink_to(repo / "config")  # the workflow's default config, beside the probe
    probe = tmp_path / "workflow" / "Snakefile"  # where the default config is found: ../config
    probe.parent.mkdir()
    probe.write_text(
        f"include: {str(repo / 'workflow' / 'Snakefile')!r}\n\n"
        f"import yaml\nopen({str(out)!r}, 'w').write(yaml.safe_dump(dict(config)))\n"
    )
    args = [
        "-n",
        "all",
        "--config",
        f"flatlandia_root={flat_root}",
        "images={missing_gps: stop}",
        "solver={top_k: 12}",
    ]
    res = smk(repo, tmp_path, *args, snakefile=probe)
    assert res.returncode == 0, res.stderr[-2000:]
    resolved = yaml.safe_load(out.read_text())
    assert resolved["images"]["missing_gps"] == "stop" and resolved["solver"]["top_k"] == 12
    assert resolved["images"]["dedup_threshold"] == config.section_defaults("images")["dedup_threshold"]
    assert resolved["solver"]["max_pairs"] == config.section_defaults("solver")["max_pairs"]
    res = smk(repo, tmp_path, "-n", "all", "--config", f"flatlandia_root={flat_root}", "sfm={matcher: fast}")
    assert res.returncode != 0
    assert (
        res.stderr.strip()
        .splitlines()[-1]
        .startswith("ERROR: config: 'sfm.matcher': 'fast' is not one of ['exhaustive', 'sequential']")
    )
