"""One home for the benchmark's names (flatlandia.vocabulary) and for its artifact paths
(flatlandia.paths); rules that name the config keys they read; one producing rule per output pattern.

The workflow is parsed through Snakemake's API in a child process (loading a workflow changes the
working directory and sets up Snakemake's logging), on the tiny committed scene: no published data,
no job runs.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from checkout_copy import copy_checkout
from conftest import REPO, smk_dry_run

from flatlandia import config, paths, vocabulary

TINY = REPO / "config" / "test" / "tiny.yaml"
RULES = REPO / "workflow" / "rules"


# ----------------------------------------------------------------------------- the vocabulary


def _schema(*keys):
    node = config.schema()
    for k in keys:
        node = node["properties"][k] if k != "items" else node["items"]
    return node


def test_the_schema_enumerates_the_vocabulary():
    """The schema's enums (what a config may name) are the vocabulary's lists: a name added to one
    and not the other fails here (docs/architecture.md, "Adding a proposal type")."""
    runs = _schema("fine", "runs")["properties"]
    external = _schema("external", "items")["properties"]
    assert tuple(runs["methods"]["items"]["enum"]) == vocabulary.METHODS
    assert tuple(external["name"]["not"]["enum"]) == vocabulary.METHODS
    for enum in (runs["map_types"]["items"]["enum"], external["map_types"]["items"]["enum"]):
        assert tuple(enum) == vocabulary.MAP_TYPES
    for enum in (runs["proposals"]["items"]["enum"], external["proposals"]["items"]["enum"]):
        assert sorted(enum) == sorted(vocabulary.PROPOSALS)
    extra = re.compile(runs["extra"]["items"]["pattern"])
    for m in vocabulary.METHODS:
        for t in vocabulary.MAP_TYPES:
            for p in vocabulary.PROPOSALS:
                assert extra.match(vocabulary.run_name(m, t, p)), (m, t, p)
    assert tuple(_schema("coarse", "losses")["items"]["enum"]) == tuple(vocabulary.COARSE_LOSSES)
    assert tuple(_schema("fine", "coarse_strategy")["enum"]) == (*vocabulary.COARSE_STRATEGIES, "GT-BB")
    box = (*vocabulary.COARSE_STRATEGIES, vocabulary.BOX_STRATEGY)
    assert tuple(_schema("coarse", "solver", "fine_strategy")["enum"]) == box


def test_every_proposal_names_what_a_run_on_it_needs():
    """A map region has no table and no strategy; a coarse proposal names its table's source, the
    config key of its strategy (a key of the config) and reads the scale prior alone."""
    defaults = config.section_defaults()
    for slug, p in vocabulary.PROPOSALS.items():
        assert re.fullmatch(r"[a-z0-9-]+", slug) and "_" not in slug  # a run name's last part
        assert p.priors in vocabulary.PRIOR_REGIONS
        if p.coarse:
            assert vocabulary.coarse_strategy(slug, defaults) in vocabulary.STRATEGIES
            assert vocabulary.coarse_proposal(p.coarse) == slug and p.priors == "scale"
            assert paths.proposal_table(slug) == f"results/coarse/{p.coarse}/proposals.parquet"
        else:
            assert not p.strategy_key and vocabulary.coarse_strategy(slug, defaults) is None
    assert vocabulary.strategy_label("coarse-simtrip", "2N_LM") == "Sim+Trip 2N_LM"
    assert vocabulary.strategy_label("gtbb") == "GT-BB" and vocabulary.strategy_label("whole") == "whole map"
    assert vocabulary.coarse_strategy("coarse-solver", defaults) == defaults["coarse"]["solver"]["fine_strategy"]
    assert vocabulary.coarse_strategy("coarse-sim", defaults) == defaults["fine"]["coarse_strategy"]
    with pytest.raises(KeyError, match="unknown proposal 'box'"):
        vocabulary.proposal("box")


def test_a_run_on_the_solvers_boxes_evaluates_the_gtbb_trained_model():
    assert vocabulary.train_regime("coarse-simtrip", "2N_LM", True) == "coarse"
    assert vocabulary.train_regime("coarse-solver", "BB", True) == "gtbb"
    assert vocabulary.train_regime("coarse-simtrip", "2N_LM", False) == "gtbb"
    assert vocabulary.train_regime("whole", None, True) == "gtbb"


def test_run_names_split_back_whatever_the_method_holds():
    for method in (*vocabulary.METHODS, "my_method_2"):
        name = vocabulary.run_name(method, "depth", "coarse-sim")
        assert vocabulary.split_run(name) == (method, "depth", "coarse-sim")


# ----------------------------------------------------------------------------- the paths


def test_a_path_function_gives_the_pattern_and_each_jobs_file():
    assert paths.reference_map() == "results/{scene}/maps/reference_map.parquet"
    assert paths.reference_map(12, "geojson") == "results/12/maps/reference_map.geojson"
    assert paths.fine_run() == "results/fine/{method}_{map_type}_{proposal}/errors.parquet"
    assert paths.external_run() == "results/external/{method}_{map_type}_{proposal}/errors.parquet"
    assert paths.run_file("solver_depth_whole", "summary.json") == "results/fine/solver_depth_whole/summary.json"
    assert paths.run_file("mine_gt_coarse-sim") == "results/external/mine_gt_coarse-sim/errors.parquet"
    assert paths.proposal_priors("whole") == "results/solver/priors/whole.json"
    assert paths.proposal_priors("coarse-solver") == "results/solver/priors/scale.json"
    assert paths.city_result(5, "index", "errors") == "results/city/5/errors_index.parquet"
    assert paths.beyond_scene("off") == "results/beyond/scene/summary_off.json"


def test_a_results_folder_elsewhere_is_found_and_reached(tmp_path):
    run = tmp_path / "copy of a run" / "results"
    file = paths.within(run, paths.reference_map("12"))
    assert file == run / "12" / "maps" / "reference_map.parquet"
    assert paths.locate(file, paths.reference_map) == (run, {"scene": "12"})
    assert paths.locate(run / "12" / "maps" / "viewer.html", paths.reference_map) is None
    assert paths.locate("results/12/maps/reference_map.geojson", paths.reference_map, ext="geojson") == (
        Path("results"),
        {"scene": "12"},
    )


def _string_literals(text: str) -> list[str]:
    return re.findall(r"""\b[rf]?["']results/[^"']*["']""", text)


def test_the_rules_build_every_path_with_flatlandia_paths():
    """No rule file (nor the Snakefile) types a results path: each comes from a function of
    flatlandia.paths (issue 37: 236 such literals before, 125 distinct)."""
    files = [*RULES.rglob("*.smk"), REPO / "workflow" / "Snakefile", REPO / "Snakefile"]
    found = {str(f.relative_to(REPO)): _string_literals(f.read_text()) for f in files}
    assert not {f: lits for f, lits in found.items() if lits}


# ----------------------------------------------------------------------------- the workflow's rules

_DESCRIBE = r"""
import json, sys
from pathlib import Path

from snakemake.api import SnakemakeApi
from snakemake.io import strip_wildcard_constraints
from snakemake.settings.types import ConfigSettings, OutputSettings, Quietness, ResourceSettings

snakefile, workdir, configfile = sys.argv[1:4]
rules = {}
with SnakemakeApi(OutputSettings(quiet={Quietness.ALL})) as api:
    workflow = api.workflow(
        resource_settings=ResourceSettings(cores=1),
        config_settings=ConfigSettings(configfiles=[Path(configfile)]),
        snakefile=Path(snakefile),
        workdir=Path(workdir),
    )._workflow
    for rule in workflow.rules:
        rules[rule.name] = {
            "outputs": [strip_wildcard_constraints(str(o)) for o in rule.output],
            "params": [str(n) for n in rule.params._names] if hasattr(rule.params, "_names") else [],
        }
print(json.dumps(rules))
"""


@pytest.fixture(scope="module")
def parsed_rules(tmp_path_factory) -> dict:
    """Every rule of the workflow as Snakemake parses it on the tiny scene, with an external method."""
    wd = tmp_path_factory.mktemp("parse")
    (wd / "mine.csv").write_text("scene,token,x_m,y_m,theta_deg\n")
    cfg = wd / "cfg.yaml"
    cfg.write_text(
        yaml.safe_dump({**yaml.safe_load(TINY.read_text()), "external": [{"name": "mine", "poses": "mine.csv"}]})
    )
    res = subprocess.run(
        [sys.executable, "-c", _DESCRIBE, str(REPO / "workflow" / "Snakefile"), str(wd), str(cfg)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=wd,
        env={k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"},
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_no_two_rules_share_an_output_pattern(parsed_rules):
    """Every output pattern has one producing rule (wildcard names aside: a pattern that differs only
    in how its wildcards are named is the same pattern); external runs have a tree of their own."""
    owner = {}
    for name, rule in parsed_rules.items():
        for out in rule["outputs"]:
            shape = re.sub(r"\{[^}]*\}", "{}", out)
            assert shape not in owner or owner[shape] == name, f"{out}: rules {owner[shape]} and {name}"
            owner[shape] = name
    assert paths.external_run() in parsed_rules["external_eval"]["outputs"]
    assert paths.fine_run() in parsed_rules["fine_eval"]["outputs"]


def test_rules_name_the_config_keys_they_read(parsed_rules):
    """A rule's params that come from the config are named by their dotted keys (config_keys), each a
    key of the schema; no param hands a script a computed settings dict (``p=``) any more."""
    schema_keys = set(_dotted(config.section_defaults()))
    named = {n for rule in parsed_rules.values() for n in rule["params"] if "." in n or n in config.section_defaults()}
    assert {"solver", "fine.coarse_strategy", "city.search", "images.align.mode", "seed"} <= named
    for key in named:
        assert key.replace(".{model}", ".mlp") in schema_keys, key
    assert "p" not in {n for rule in parsed_rules.values() for n in rule["params"]}
    assert set(parsed_rules["fine_eval"]["params"]) == {
        "solver",
        "fine.coarse_strategy",
        "coarse.solver.fine_strategy",
        "fine.coarse_training.enabled",
        "fine.coarse_training.crop_m",
    }


def _dotted(d: dict, prefix: str = ""):
    for k, v in d.items():
        yield prefix + k
        if isinstance(v, dict):
            yield from _dotted(v, prefix + k + ".")


# ----------------------------------------------------------------------------- adding a proposal type


def test_a_new_proposal_type_is_two_edits(tmp_path):
    """Adding a coarse proposal type touches two files: one Proposal in flatlandia/vocabulary.py and
    the schema's enums of proposals. On a copy of the checkout with just these edits, the workflow
    plans the fine runs on it (reading its table), and score and the export know it."""
    copy = copy_checkout(tmp_path / "repo")
    vocab = copy / "workflow" / "flatlandia" / "vocabulary.py"
    anchor = '        Proposal("whole", "whole map", "whole reference map", priors="whole"),\n'
    new = '        Proposal("coarse-demo", "Demo", "coarse proposals (Demo)", "demo", "fine.coarse_strategy"),\n'
    text = vocab.read_text()
    assert text.count(anchor) == 1
    vocab.write_text(text.replace(anchor, new + anchor))
    schema = copy / "workflow" / "schemas" / "config.schema.yaml"
    text = schema.read_text()
    enum = "coarse-sim, coarse-trip, coarse-simtrip, coarse-solver]"
    assert text.count(enum) == 2 and text.count("coarse-simtrip|coarse-solver)") == 1
    text = text.replace(enum, enum[:-1] + ", coarse-demo]")
    schema.write_text(text.replace("coarse-simtrip|coarse-solver)", "coarse-simtrip|coarse-solver|coarse-demo)"))

    wd = tmp_path / "run"
    table = wd / "results" / "coarse" / "demo" / "proposals.parquet"  # a coarse stage of its own writes it
    table.parent.mkdir(parents=True)
    table.write_bytes(b"")
    runs = {"methods": ["solver", "mlp"], "map_types": ["depth"], "proposals": ["coarse-demo"], "extra": []}
    cfg = wd / "demo.yaml"
    cfg.write_text(yaml.safe_dump({"fine": {"runs": runs}}))
    env = {"PYTHONPATH": str(copy / "workflow")}
    res = smk_dry_run(
        copy, wd, "results/tables/fine_localization.parquet", "--configfile", str(TINY), str(cfg), env=env
    )
    assert res.returncode == 0, res.stderr[-3000:] + res.stdout[-3000:]
    planned = res.stdout
    for method in ("solver", "mlp"):
        assert f"output: results/fine/{method}_depth_coarse-demo/errors.parquet" in planned
    fine_eval = [block for block in planned.split("\n\n") if "rule fine_eval:" in block]
    assert len(fine_eval) == 2 and all("results/coarse/demo/proposals.parquet" in b for b in fine_eval)
    assert "results/fine/models/mlp_depth_coarse/checkpoint.pt" in planned  # trained on simulated coarse proposals

    check = (
        "from flatlandia import score, vocabulary\n"
        "from flatlandia.report import figures\n"
        "from flatlandia.data import export\n"
        "assert 'coarse-demo' in export.COARSE_SOURCES and figures.PROPOSAL_LABELS['coarse-demo']\n"
        "assert vocabulary.strategy_label('coarse-demo', '2N_LM') == 'Demo 2N_LM'\n"
        "assert score.default_strategy('coarse-demo') == '2N_LM'\n"
    )
    res = subprocess.run([sys.executable, "-c", check], env={**os.environ, **env}, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]


def test_a_key_with_a_wildcard_is_the_jobs_entry(tmp_path):
    """fine_train reads fine.train_overrides.{model}: the job's model's entry, recorded under that name."""
    from flatlandia.plumbing import debug, provenance

    job = debug.mock_snakemake(
        "fine_train", workdir=tmp_path, configfiles=[TINY], model="gat", map_type="gt", train="coarse"
    )
    settings = provenance.rule_settings(job)
    overrides = config.section_defaults("fine")["train_overrides"]
    assert {"fine.train", "fine.train_overrides.{model}", "fine.coarse_training"} <= set(settings)
    if overrides["gat"]:
        assert settings["fine.train_overrides.{model}"] == overrides["gat"]
    assert job.params.model == vocabulary.LEARNED_METHODS["gat"]
