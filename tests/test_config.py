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


@dataclasses.dataclass
class _Toy:
    top_k: int = 0
    model: str = "x"


def test_from_section_is_strict_and_takes_the_schema_defaults():
    toy = config.from_section(_Toy, "solver", {}, model="mlp")
    assert toy == _Toy(top_k=config.section_defaults("solver")["top_k"], model="mlp")
    with pytest.raises(config.ConfigError, match="'solver.top_kk' \\(did you mean 'solver.top_k'\\?\\)"):
        config.from_section(_Toy, "solver", {"top_kk": 1})


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
