"""Snakemake workflow catalog conventions: the catalog's usage settings, every job rule in the one
pinned conda env, every figure in the report with a caption, the default workflow profile.

The workflow is read through Snakemake's own API (rules, conda envs, report flags) in a child
process: loading a workflow changes the working directory and sets up Snakemake's logging.
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
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

REPO = Path(__file__).resolve().parents[1]
CATALOG = REPO / ".snakemake-workflow-catalog.yml"
ENV_FILE = REPO / "workflow" / "envs" / "flatlandia.yaml"
#: pinned in envs/requirements.txt to run the workflow, but not imported by the rule scripts: the
#: host's tools, outside the rules' conda env
HOST_TOOLS = {"snakemake", "snakemake-executor-plugin-slurm"}
#: the CPU build of torch, named in the conda env (PyPI's torch for Linux is the CUDA build)
CPU_TORCH_INDEX = "https://download.pytorch.org/whl/cpu"
REPORT_DIR = REPO / "workflow" / "report"
FIGURE_SUFFIXES = (".png", ".svg", ".pdf", ".html")
# the deployment methods the catalog knows (it reads singularity as apptainer)
DEPLOYMENT_METHODS = {"conda", "apptainer", "apptainer+conda", "singularity", "singularity+conda"}

_DESCRIBE = r"""
import json, sys
from pathlib import Path

from snakemake.api import SnakemakeApi
from snakemake.io import get_flag_value, is_flagged, strip_wildcard_constraints
from snakemake.settings.types import ConfigSettings, OutputSettings, Quietness, ResourceSettings

snakefile, workdir, root = sys.argv[1:4]
rules = {}
with SnakemakeApi(OutputSettings(quiet={Quietness.ALL})) as api:
    workflow = api.workflow(
        resource_settings=ResourceSettings(cores=1),
        config_settings=ConfigSettings(config={"flatlandia_root": root}),
        snakefile=Path(snakefile),
        workdir=Path(workdir),
    )._workflow
    for rule in workflow.rules:
        env = rule.expand_conda_env({}) if rule.conda_env is not None else None
        outputs = []
        for out in rule.output:
            report = get_flag_value(out, "report") if is_flagged(out, "report") else None
            outputs.append({
                "path": strip_wildcard_constraints(str(out)),
                "report": report is not None,
                "caption": report.caption.get_path_or_uri(secret_free=True) if report and report.caption else None,
                "category": report.category if report else None,
            })
        rules[rule.name] = {
            "runs_code": not rule.norun,
            "conda_env": str(env.file.get_path_or_uri(secret_free=True)) if env is not None and env.is_file else None,
            "conda_spec": None if rule.conda_env is None else str(rule.conda_env),
            "container": bool(rule.container_img),
            "outputs": outputs,
        }
print(json.dumps(rules))
"""


def describe(workdir: Path, root: Path) -> dict:
    """Every rule of the workflow as Snakemake parsed it, with the data root ``root``."""
    res = subprocess.run(
        [sys.executable, "-c", _DESCRIBE, str(REPO / "workflow" / "Snakefile"), str(workdir), str(root)],
        capture_output=True,
        text=True,
        timeout=300,
        env={k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"},  # it would override ``root``
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def rules(flat_root, tmp_path_factory) -> dict:
    """The rules with the data present, plus those defined only when it is missing (the download)."""
    present = describe(tmp_path_factory.mktemp("present"), flat_root)
    missing_root = tmp_path_factory.mktemp("missing") / "no_data_here"
    missing = describe(missing_root.parent, missing_root)
    assert "fetch_flatlandia" in missing and "ingest" in present
    return missing | present


def test_catalog_settings_have_the_keys_the_catalog_reads():
    settings = yaml.safe_load(CATALOG.read_text())
    usage = settings["usage"]
    assert set(usage) <= {"mandatory-flags", "software-stack-deployment", "report"}, set(usage)

    flags = usage["mandatory-flags"]
    assert isinstance(flags["desc"], str) and flags["desc"].strip()
    assert isinstance(flags["flags"], str) or all(isinstance(f, str) for f in flags["flags"])

    deployment = usage["software-stack-deployment"]
    assert set(deployment) <= DEPLOYMENT_METHODS, set(deployment) - DEPLOYMENT_METHODS
    assert all(isinstance(v, bool) for v in deployment.values()), deployment
    assert any(deployment.values()), "the catalog needs at least one deployment method"
    assert usage["report"] is True

    # what the catalog's standardized usage takes from the repository beside the settings
    assert (REPO / "config" / "config.yaml").is_file()
    assert (REPO / "config" / "README.md").read_text().strip()


@pytest.mark.slow  # the published data (flat_root)
def test_catalog_deployment_claims_match_the_rules(rules):
    deployment = yaml.safe_load(CATALOG.read_text())["usage"]["software-stack-deployment"]
    jobs = {name: r for name, r in rules.items() if r["runs_code"]}
    if deployment.get("conda"):
        assert not [n for n, r in jobs.items() if r["conda_env"] is None], "job rules without a conda env file"
    containers = sorted(n for n, r in jobs.items() if r["container"])
    uses_containers = any(deployment.get(k) for k in DEPLOYMENT_METHODS - {"conda"})
    assert bool(containers) == uses_containers, containers


@pytest.mark.slow  # the published data (flat_root)
def test_every_job_rule_runs_in_the_pinned_conda_env(rules):
    targets = {name for name, r in rules.items() if not r["runs_code"]}
    assert {"all", "maps", "benchmark", "tables"} <= targets
    for name, r in rules.items():
        if not r["runs_code"]:
            continue
        assert r["conda_env"] is not None, (name, r["conda_spec"])
        env = Path(r["conda_env"]).resolve()
        assert env == ENV_FILE.resolve() and env.is_file(), (name, env)


def _pins(lines) -> dict[str, Requirement]:
    reqs = {}
    for line in lines:
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            req = Requirement(line)
            reqs[canonicalize_name(req.name)] = req
    return reqs


def _exact(req: Requirement) -> Version:
    (spec,) = req.specifier
    assert spec.operator == "==", req
    return Version(spec.version)


@pytest.mark.parametrize("pins", ["requirements.txt", "requirements-dev.txt"])
def test_requirements_agree_with_the_full_freeze(pins):
    requirements = _pins((REPO / "envs" / pins).read_text().splitlines())
    freeze = _pins((REPO / "envs" / "constraints.txt").read_text().splitlines())
    assert requirements
    for name, req in requirements.items():
        assert name in freeze, f"{name} is pinned in {pins} but missing from constraints.txt"
        assert _exact(req).public == _exact(freeze[name]).public, (req, freeze[name])


def test_development_tools_stay_out_of_the_workflows_requirements():
    run = _pins((REPO / "envs" / "requirements.txt").read_text().splitlines())
    dev = _pins((REPO / "envs" / "requirements-dev.txt").read_text().splitlines())
    assert {"pytest", "pytest-xdist", "selenium", "ruff", "snakefmt", "snakedeploy"} <= set(dev)
    assert not set(run) & set(dev), set(run) & set(dev)
    assert HOST_TOOLS <= set(run)


def test_conda_env_is_self_contained_and_pins_the_requirements():
    """Snakemake copies only the env file into .snakemake/conda/<hash>.yaml and conda runs pip from
    there, so a relative -r/-c/-e path in its pip section points into .snakemake/conda/."""
    env = yaml.safe_load(ENV_FILE.read_text())
    pip = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict) and "pip" in d)
    file_option = re.compile(r"^(-r|-c|-e|--requirement|--constraint|--editable)[\s=]*(?P<target>.*)$")
    for entry in pip:
        m = file_option.match(entry.strip())
        target = m.group("target") if m else entry.strip()
        local = target.startswith((".", "/")) and "${" not in target
        assert not (m and m.group(1) in ("-r", "-c", "--requirement", "--constraint")), entry
        assert not local, f"{entry!r}: a path relative to the env file does not survive Snakemake's copy"

    in_env = _pins(e for e in pip if not file_option.match(e.strip()))
    requirements = _pins((REPO / "envs" / "requirements.txt").read_text().splitlines())
    runtime = {name: req for name, req in requirements.items() if name not in HOST_TOOLS}
    assert sorted(in_env) == sorted(runtime), set(in_env) ^ set(runtime)
    freeze = _pins((REPO / "envs" / "constraints.txt").read_text().splitlines())
    for name, req in runtime.items():  # the versions the test suite runs with
        assert _exact(in_env[name]).public == _exact(req).public == _exact(freeze[name]).public, (in_env[name], req)
    # the CPU build of torch, from PyTorch's CPU index (the suite's torch is that build too)
    assert _exact(in_env["torch"]).local == "cpu", in_env["torch"]
    assert f"--extra-index-url {CPU_TORCH_INDEX}" in [e.strip() for e in pip], pip


def test_the_rules_conda_env_holds_no_development_tool():
    env = yaml.safe_load(ENV_FILE.read_text())
    pip = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict) and "pip" in d)
    names = set(_pins(pip))
    dev = set(_pins((REPO / "envs" / "requirements-dev.txt").read_text().splitlines()))
    assert not names & (dev | HOST_TOOLS), names & (dev | HOST_TOOLS)
    assert ENV_FILE.parent == REPO / "workflow" / "envs" and not (REPO / "envs" / "flatlandia.yaml").exists()


@pytest.mark.slow  # the published data (flat_root)
def test_every_figure_is_in_the_report_with_a_caption(rules):
    figures = [
        (name, out) for name, r in rules.items() for out in r["outputs"] if out["path"].endswith(FIGURE_SUFFIXES)
    ]
    assert len(figures) >= 7, figures
    for name, out in figures:
        assert out["report"], f"{name}: {out['path']} is not wrapped in report()"
        assert out["caption"], f"{name}: {out['path']} has no caption"
        assert out["category"], f"{name}: {out['path']} has no category"
        caption = Path(out["caption"]).resolve()
        assert caption.parent == REPORT_DIR.resolve() and caption.suffix == ".rst", caption
        assert caption.is_file() and caption.read_text().strip(), caption


@pytest.mark.parametrize("caption", sorted(REPORT_DIR.glob("*.rst")), ids=lambda p: p.stem)
def test_caption_renders_as_the_report_renders_it(caption):
    """Snakemake's report renders a caption with jinja2, then docutils; any RST warning fails here."""
    from types import SimpleNamespace

    from docutils.core import publish_parts
    from jinja2 import Environment, StrictUndefined

    text = caption.read_text()
    smk = SimpleNamespace(wildcards=SimpleNamespace(scene="12"))
    rendered = Environment(trim_blocks=True, lstrip_blocks=True, undefined=StrictUndefined).from_string(text)
    rst = rendered.render(snakemake=smk, categories={}, files=[])
    html = publish_parts(rst, writer="html", settings_overrides={"halt_level": 2, "report_level": 5})["body"]
    sentences = len(re.findall(r"[.!?](?:\s|$)", text))
    assert html.strip() and 1 <= sentences <= 6, (caption.name, sentences)


@pytest.mark.slow  # the published data (flat_root)
def test_every_caption_file_is_used(rules):
    used = {Path(o["caption"]).resolve() for r in rules.values() for o in r["outputs"] if o["caption"]}
    # workflow.rst is the report's landing page (the Snakefile's `report:`), not a caption
    landing = REPORT_DIR / "workflow.rst"
    unused = sorted(p.name for p in REPORT_DIR.glob("*.rst") if p.resolve() not in used and p != landing)
    assert not unused, unused


def test_default_workflow_profile_is_found_beside_the_snakefile(tmp_path):
    """Run from an unrelated folder, Snakemake finds workflow/profiles/default next to workflow/Snakefile."""
    code = (
        "import json, sys; from snakemake.cli import parse_args; "
        "_, a = parse_args(['-s', sys.argv[1], '-n']); "
        "print(json.dumps({'cores': a.cores, 'printshellcmds': a.printshellcmds}))"
    )
    res = subprocess.run(
        [sys.executable, "-c", code, str(REPO / "workflow" / "Snakefile")], cwd=tmp_path, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr[-2000:]
    profile = REPO / "workflow" / "profiles" / "default"
    assert f"workflow specific profile {profile}" in res.stderr, res.stderr
    settings = yaml.safe_load((profile / "config.yaml").read_text())
    parsed = json.loads(res.stdout.strip().splitlines()[-1])
    assert int(parsed["cores"]) == settings["cores"] and parsed["printshellcmds"] is settings["printshellcmds"]


def test_the_top_level_snakefile_runs_the_workflow_with_its_default_profile(tmp_path):
    """The design's layout: `snakemake` from the repository root finds ./Snakefile, which includes
    workflow/Snakefile (the catalog's layout) and gets the default profile through ./profiles."""
    import subprocess
    import sys

    exe = str(Path(sys.executable).parent / "snakemake")
    res = subprocess.run(
        [exe, "-n", "maps", "-d", str(tmp_path), "--configfile", "config/test/tiny.yaml"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    out = res.stdout + res.stderr
    assert "profiles/default" in out and "reference_map" in out
    assert (REPO / "Snakefile").read_text().count('include: "workflow/Snakefile"') == 1
    assert (REPO / "profiles").resolve() == (REPO / "workflow" / "profiles").resolve()
