"""The Python package as Python users install it (issue 35): a wheel that carries every module, the
config schema, the viewer's assets and the `flatlandia` command, installed (not editable) into a
fresh virtual environment outside the repository, where `flatlandia --version`, `flatlandia
localize` and `flatlandia score` run on the tiny scene without the workflow's heavy dependencies;
the declared dependencies hold the tested pins; one version everywhere; LICENSE, CITATION.cff,
CHANGELOG.md."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pandas as pd
import pytest
import tiny_results
import yaml
from checkout_copy import copy_checkout
from conftest import REPO, TINY_SCENE
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

from flatlandia import __version__, cli, release
from flatlandia.classes import CLASSES
from flatlandia.plumbing import provenance

PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
VERSION = PYPROJECT["project"]["version"]
PACKAGE = REPO / "workflow" / "flatlandia"
#: where the package's data files come from in the tree -> where the wheel puts them
DATA_FOLDERS = {REPO / "workflow" / "schemas": "flatlandia/schemas"}


def _pins(path: Path) -> dict[str, Version]:
    """name -> pinned version of a requirements or constraints file."""
    out = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            req = Requirement(line)
            (spec,) = req.specifier
            out[canonicalize_name(req.name)] = Version(spec.version)
    return out


def package_tree() -> set[str]:
    """Every file the wheel must carry, as its path inside the wheel."""
    files = {
        f"flatlandia/{p.relative_to(PACKAGE).as_posix()}"
        for p in PACKAGE.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    }
    for folder, inside in DATA_FOLDERS.items():
        files |= {f"{inside}/{p.name}" for p in folder.iterdir() if p.is_file()}
    return files


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """`pip wheel . --no-deps --no-build-isolation` of a copy of the checkout (a build writes build/
    and *.egg-info beside the sources)."""
    source = copy_checkout(tmp_path_factory.mktemp("source"))
    out = tmp_path_factory.mktemp("wheel")
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    (path,) = out.glob("flatlandia-*.whl")
    return path


def test_the_wheel_carries_the_whole_package_and_the_command(wheel):
    assert wheel.name == f"flatlandia-{VERSION}-py3-none-any.whl"
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        info = f"flatlandia-{VERSION}.dist-info"
        carried = {n for n in names if not n.startswith(f"{info}/")}
        assert carried == package_tree(), (sorted(package_tree() - carried), sorted(carried - package_tree()))
        assert {"flatlandia/schemas/config.schema.yaml", "flatlandia/viewer/assets/viewer.js"} <= carried
        entry_points = z.read(f"{info}/entry_points.txt").decode()
        assert "flatlandia = flatlandia.cli:main" in entry_points
        metadata = z.read(f"{info}/METADATA").decode()
        assert f"Version: {VERSION}\n" in metadata and "License-Expression: MIT\n" in metadata
        assert z.read(f"{info}/licenses/LICENSE") == (REPO / "LICENSE").read_bytes()


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh virtual environment outside the repository with the wheel installed (not editable,
    offline: --no-deps), its dependencies seen from the test suite's own environment through a .pth
    line (the suite's editable flatlandia there is not: its .pth is not read). Returns its bin/."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    bin_dir = venv / "bin"
    # the wheel first: with the suite's environment in view, pip would find its flatlandia installed
    res = _in_venv(bin_dir, "python", "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel), cwd=venv)
    assert res.returncode == 0, res.stderr[-3000:]
    purelib = _in_venv(bin_dir, "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])", cwd=venv)
    (Path(purelib.stdout.strip()) / "suite_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return bin_dir


def _in_venv(bin_dir: Path, *cmd: str, cwd: Path) -> subprocess.CompletedProcess:
    """A command of the virtual environment, with nothing of this checkout on its path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run([str(bin_dir / cmd[0]), *cmd[1:]], cwd=cwd, capture_output=True, text=True, env=env)


#: run in the installed package: localize, then score, then which distributions were imported
_LOCALIZE_AND_SCORE = r"""
import json, sys
from importlib.metadata import packages_distributions
import flatlandia
from flatlandia import cli

map_, query, loc_out, poses, score_out, results = sys.argv[1:7]
assert cli.main(["localize", "--map", map_, "--query", query, "--out", loc_out]) == 0
assert cli.main(["score", poses, "--name", "mine", "--out", score_out, "--results", results, "--split", "train"]) == 0
dists = packages_distributions()
imported = sorted({d for m in list(sys.modules) for d in dists.get(m.split(".")[0], [])})
print(json.dumps({"file": flatlandia.__file__, "imported": imported}))
"""


def _without_timing(value):
    if isinstance(value, dict):
        return {k: _without_timing(v) for k, v in value.items() if k != "seconds"}
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


@pytest.mark.slow
def test_the_installed_wheel_localizes_and_scores_without_the_heavy_dependencies(installed, tmp_path, capsys):
    """Outside the repository, the wheel's own copy runs `flatlandia --version`, `localize` and
    `score` on the tiny scene with the results of this checkout's code, importing none of the
    extras (torch, pycolmap, open3d, snakemake, ...)."""
    res = _in_venv(installed, "flatlandia", "--version", cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.strip() == f"flatlandia {VERSION}", res.stdout + res.stderr

    results = tiny_results.build(tmp_path / "results")
    q = pd.read_parquet(results / TINY_SCENE / "queries" / "queries.parquet")
    test_query = q[q["split"] == "test"].iloc[0]
    objects = [
        {"class": CLASSES[c], "x": float(x), "y": float(y)}
        for c, (x, y) in zip(test_query["classes"], test_query["gt_local_xy_m"])
    ]
    (tmp_path / "q.json").write_text(json.dumps({"objects": objects}))
    q[q["split"] == "train"][["scene", "token", "x_m", "y_m", "theta_deg"]].to_csv(tmp_path / "poses.csv", index=False)
    ref_map = results / TINY_SCENE / "maps" / "reference_map.parquet"

    def args(tag):
        return [str(ref_map), str(tmp_path / "q.json"), str(tmp_path / f"loc_{tag}.json")] + [
            str(tmp_path / "poses.csv"),
            str(tmp_path / f"scores_{tag}"),
            str(results),
        ]

    res = _in_venv(installed, "python", "-c", _LOCALIZE_AND_SCORE, *args("wheel"), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stdout.strip().splitlines()[-1])
    assert Path(report["file"]).is_relative_to(installed.parent), report["file"]  # the wheel's copy

    # the same commands in this process, with this checkout's code
    map_, query, loc_out, poses, score_out, results_dir = args("here")
    assert cli.main(["localize", "--map", map_, "--query", query, "--out", loc_out]) == 0
    assert (
        cli.main(["score", poses, "--name", "mine", "--out", score_out, "--results", results_dir, "--split", "train"])
        == 0
    )
    capsys.readouterr()
    loc = {tag: json.loads((tmp_path / f"loc_{tag}.json").read_text()) for tag in ("wheel", "here")}
    assert loc["wheel"]["found"] and _without_timing(loc["wheel"]) == _without_timing(loc["here"])
    assert (tmp_path / "scores_wheel" / "scores.md").read_text() == (tmp_path / "scores_here" / "scores.md").read_text()
    errors = {tag: pd.read_parquet(tmp_path / f"scores_{tag}" / "mine_depth_whole" / "errors.parquet") for tag in loc}
    pd.testing.assert_frame_equal(errors["wheel"], errors["here"])

    heavy = {canonicalize_name(Requirement(r).name) for r in PYPROJECT["project"]["optional-dependencies"]["workflow"]}
    imported = {canonicalize_name(d) for d in report["imported"]}
    assert not imported & heavy, sorted(imported & heavy)
    core = {canonicalize_name(Requirement(r).name) for r in PYPROJECT["project"]["dependencies"]}
    assert core <= imported, sorted(core - imported)  # every declared dependency is used


def test_the_declared_dependencies_hold_the_tested_pins():
    """pyproject's ranges contain the versions the suite runs with (envs/constraints.txt), and the
    dependencies with their extras are exactly what running the workflow needs (envs/requirements.txt)."""
    freeze = _pins(REPO / "envs" / "constraints.txt")
    project = PYPROJECT["project"]
    declared = [Requirement(r) for r in project["dependencies"]] + [
        Requirement(r) for extra in project["optional-dependencies"].values() for r in extra
    ]
    for req in declared:
        pin = freeze[canonicalize_name(req.name)]
        assert req.specifier.contains(Version(pin.public), prereleases=True), (str(req), str(pin))
    names = {canonicalize_name(r.name) for r in declared}
    assert names == set(_pins(REPO / "envs" / "requirements.txt")), names ^ set(
        _pins(REPO / "envs" / "requirements.txt")
    )
    ranges: dict[str, set[str]] = {}
    for req in declared:  # one in several extras (matplotlib: workflow and plot) with one range
        ranges.setdefault(canonicalize_name(req.name), set()).add(str(req))
    assert all(len(r) == 1 for r in ranges.values()), {n: r for n, r in ranges.items() if len(r) > 1}
    assert len(names) == len(project["dependencies"]) + len(
        {canonicalize_name(Requirement(r).name) for extra in project["optional-dependencies"].values() for r in extra}
    ), "a dependency both required and in an extra"
    assert {"torch", "torch-geometric", "transformers", "pycolmap", "open3d", "snakemake"} <= {
        canonicalize_name(Requirement(r).name) for r in project["optional-dependencies"]["workflow"]
    }


def test_one_version_everywhere(capsys):
    """pyproject.toml's version is the package's, `flatlandia --version`'s, the provenance records',
    CITATION.cff's and CHANGELOG.md's newest entry's."""
    assert __version__ == release.package_version() == VERSION
    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"flatlandia {VERSION}"
    assert provenance.software_versions()["flatlandia"] == VERSION
    assert yaml.safe_load((REPO / "CITATION.cff").read_text())["version"] == VERSION
    changelog = (REPO / "CHANGELOG.md").read_text()
    assert changelog.split("\n## ")[1].startswith(f"[{VERSION}]"), changelog[:300]


def test_a_workflow_of_another_version_is_named_with_what_to_install(tmp_path):
    other = tmp_path / "pyproject.toml"
    other.write_text((REPO / "pyproject.toml").read_text().replace(f'version = "{VERSION}"', 'version = "99.0.0"', 1))
    problem = release.workflow_package_mismatch(other)
    assert "flatlandia 99.0.0" in problem and f"flatlandia {VERSION}" in problem and "v99.0.0" in problem
    assert release.workflow_package_mismatch(REPO / "pyproject.toml") == ""
    assert release.workflow_package_mismatch(tmp_path / "missing.toml") == ""  # nothing to compare with


def test_license_and_citation():
    assert PYPROJECT["project"]["license"] == "MIT" and PYPROJECT["project"]["license-files"] == ["LICENSE"]
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License") and "Permission is hereby granted, free of charge" in text
    cff = yaml.safe_load((REPO / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["license"] == "MIT" and cff["type"] == "software"
    assert cff["message"] and cff["title"] and cff["authors"]
    (paper,) = [r for r in cff["references"] if "Flatlandia" in r["title"]]
    assert [a["family-names"] for a in paper["authors"]] == ["Toso", "Taiana", "James", "Del Bue"]
    assert "2304.06373" in paper["url"]
