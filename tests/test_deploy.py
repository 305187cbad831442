"""Deploying the workflow the ways Snakemake users do (issue 35): `snakemake` from the repository root
(the default target `all`, the report), the workflow as a module of a user's own project loaded
from its repository at a release tag (what `snakedeploy deploy-workflow URL DEST --tag vX` writes:
`github(...)`; offline here: git's url.<base>.insteadOf points github.com at a tagged copy of this
checkout), `snakemake --lint` in a bare clone and with the data, and explicit configuration over
the environment variable FLATLANDIA_ROOT. Dry runs are fast; runs of jobs are slow."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from checkout_copy import TAG, copy_checkout, tagged_repository
from conftest import REPO, TINY_ROOT, TINY_SCENE
from snakemake_runner import SNAKEMAKE, job_stats

from flatlandia import __version__
from flatlandia.plumbing import files

#: the published repository as snakedeploy names it (served here from a local tagged copy)
GITHUB_REPO = "example/flatlandia-workflow"
TINY = ["--configfile", str(REPO / "config" / "test" / "tiny.yaml")]
#: the tiny scene with 2-epoch trainings: `all` in about 2.5 minutes on 2 cores
TINY_SMALL = [*TINY, str(REPO / "config" / "test" / "slurm_small.yaml")]
#: the Snakefile snakedeploy writes (its template use_module.smk.jinja), plus the module's handlers
USER_SNAKEFILE = f"""from snakemake.utils import min_version


min_version("6.10.0")


configfile: "config/config.yaml"


# declare https://github.com/{GITHUB_REPO} as a module
module flatlandia_workflow:
    snakefile:
        {{source}}
    config:
        config


# use all rules from https://github.com/{GITHUB_REPO}
use rule * from flatlandia_workflow


# a module's onstart/onsuccess run only when the user's Snakefile calls them
onstart:
    flatlandia_workflow.onstart()


onsuccess:
    flatlandia_workflow.onsuccess()
"""


def run(cwd: Path, *args: str, env: dict | None = None, timeout: int = 900) -> subprocess.CompletedProcess:
    """`snakemake ARGS` in ``cwd``, as a user types it (no FLATLANDIA_ROOT unless ``env`` gives one)."""
    full_env = {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"} | (env or {})
    return subprocess.run([SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True, env=full_env, timeout=timeout)


def job_counts(res: subprocess.CompletedProcess) -> dict[str, int]:
    """Snakemake's "Job stats" table of a run or dry run: rule -> jobs (and 'total')."""
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    return job_stats(res.stdout)


def github_env(repository: Path, cache: Path) -> dict:
    """Git fetches https://github.com/<GITHUB_REPO> from ``repository``; Snakemake's source cache in
    ``cache`` (not the user's ~/.cache, where an earlier test's tag would be reused)."""
    env = {k: v for k, v in os.environ.items() if k != "GITHUB_TOKEN" and not k.startswith("GIT_CONFIG")}
    return env | {
        "XDG_CACHE_HOME": str(cache),
        "GIT_CONFIG_COUNT": "1",
        "GIT_CONFIG_KEY_0": f"url.{repository.as_uri()}.insteadOf",
        "GIT_CONFIG_VALUE_0": f"https://github.com/{GITHUB_REPO}",
    }


def user_project(folder: Path, repository: Path, source: str) -> Path:
    """A user's project as snakedeploy lays it out (the repository's config/ and profiles/ copied, a
    Snakefile loading the module), with a config of its own: the defaults on the tiny scene."""
    shutil.copytree(repository / "config", folder / "config")
    shutil.copytree(repository / "profiles", folder / "profiles")
    own = yaml.safe_load((repository / "config" / "config.yaml").read_text())
    own.update(flatlandia_root=str(TINY_ROOT), scenes=str(REPO / "config" / "test" / "tiny_scenes.tsv"))
    (folder / "config" / "config.yaml").write_text(yaml.safe_dump(own, sort_keys=False))
    (folder / "workflow").mkdir()
    (folder / "workflow" / "Snakefile").write_text(USER_SNAKEFILE.format(source=source))
    return folder


@pytest.fixture(scope="module")
def release_repository(tmp_path_factory) -> Path:
    """This checkout as the published repository at its release tag (no ../shared beside it)."""
    return tagged_repository(tmp_path_factory.mktemp("remote") / "flatlandia-workflow")


@pytest.fixture(scope="module")
def repository_plan(tmp_path_factory) -> dict[str, int]:
    """The jobs `snakemake -n` plans from the repository root on the tiny scene."""
    return job_counts(run(REPO, "-n", "-d", str(tmp_path_factory.mktemp("plan")), *TINY))


@pytest.fixture
def github_project(tmp_path, release_repository):
    """(project folder, environment) of a user who deployed the release with snakedeploy."""
    source = f'github("{GITHUB_REPO}", path="workflow/Snakefile", tag="{TAG}")'
    project = user_project(tmp_path / "project", release_repository, source)
    return project, github_env(release_repository, tmp_path / "cache")


# ---------------------------------------------------------------- the repository root


def test_snakemake_from_the_repository_root_plans_all(repository_plan, tmp_path):
    """`snakemake -n` with no target plans `all` (the top-level Snakefile includes workflow/Snakefile,
    whose default target `include` would otherwise drop)."""
    named = job_counts(run(REPO, "-n", "all", "-d", str(tmp_path), *TINY))
    assert repository_plan == named and named["all"] == 1 and named["total"] > 20, named


@pytest.mark.parametrize("given", ["configfile", "config", "environment"])
def test_an_explicit_data_folder_beats_FLATLANDIA_ROOT(given, tmp_path):
    """flatlandia_root from --configfile or --config wins over FLATLANDIA_ROOT (here an empty folder);
    the environment variable names the data folder when no config does."""
    empty = tmp_path / "empty"
    empty.mkdir()
    scenes = f"scenes={REPO / 'config' / 'test' / 'tiny_scenes.tsv'}"
    args, env = {
        "configfile": (TINY, str(empty)),
        "config": (["--config", f"flatlandia_root={TINY_ROOT}", scenes], str(empty)),
        "environment": (["--config", scenes], str(TINY_ROOT)),
    }[given]
    res = run(REPO, "-n", "maps", "-d", str(tmp_path / "w"), *args, env={"FLATLANDIA_ROOT": env})
    assert job_counts(res)["ingest"] == 1
    assert f"{TINY_ROOT}/local_maps.json" in res.stdout and str(empty) not in res.stdout


@pytest.fixture(scope="module")
def default_run(tmp_path_factory) -> Path:
    """`snakemake --cores 2` from the repository root, no target, on the tiny scene (2-epoch trainings)."""
    folder = tmp_path_factory.mktemp("default_run")
    res = run(REPO, "--cores", "2", "-d", str(folder), *TINY_SMALL, timeout=1800)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    return folder


@pytest.mark.slow
def test_snakemake_from_the_repository_root_runs_all_and_reports(default_run):
    assert (default_run / "results" / "manifest.parquet").is_file()  # all's last product
    assert (default_run / "results" / "summary.md").is_file()
    # the README's `snakemake --report results/report.html`, after the run (no target: all's)
    res = run(REPO, "--report", "results/report.html", "-d", str(default_run), *TINY_SMALL)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    html = (default_run / "results" / "report.html").read_text()
    assert f"flatlandia {__version__}" in html  # the landing page names the release
    assert "dataset_stats.md" in html and "training_curves.png" in html


# ---------------------------------------------------------------- a module from a tag


@pytest.mark.slow
def test_a_module_from_a_tag_plans_the_same_jobs_as_the_repository(github_project, repository_plan):
    project, env = github_project
    module = job_counts(run(project, "-n", env=env))
    assert module == repository_plan and module["all"] == 1, (module, repository_plan)


@pytest.mark.slow
def test_a_module_of_another_release_than_the_installed_package_stops_with_one_line(tmp_path):
    """The rules import the installed package: a workflow of another version says what to install."""

    def bump(folder: Path):
        pyproject = folder / "pyproject.toml"
        pyproject.write_text(pyproject.read_text().replace(f'version = "{__version__}"', 'version = "99.0.0"', 1))

    repository = tagged_repository(tmp_path / "remote" / "flatlandia-workflow", "v99.0.0", edit=bump)
    source = f'github("{GITHUB_REPO}", path="workflow/Snakefile", tag="v99.0.0")'
    project = user_project(tmp_path / "project", repository, source)
    res = run(project, "-n", env=github_env(repository, tmp_path / "cache"))
    assert res.returncode != 0
    errors = [line for line in (res.stdout + res.stderr).splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and "flatlandia 99.0.0" in errors[0] and f"flatlandia {__version__}" in errors[0], errors
    assert "Traceback" not in res.stderr


class KnownSnakemakeBug(Exception):
    """Snakemake 9.27.1 cannot run a gitfile() module whose rules have `script:`."""


@pytest.mark.slow
@pytest.mark.xfail(
    raises=KnownSnakemakeBug,
    strict=True,
    reason="Snakemake 9.27.1: with a gitfile() module, the first rule with `script:` fails in "
    "LocalGitFile.join (TypeError: sequence item 1: expected str instance, LocalSourceFile found); "
    "github() (above) takes the hosted-git path, which joins paths as text",
)
def test_a_module_from_a_local_git_repository_plans_the_same_jobs(release_repository, repository_plan, tmp_path):
    source = f'gitfile(repo_path="{release_repository}", path="workflow/Snakefile", tag="{TAG}")'
    project = user_project(tmp_path / "project", release_repository, source)
    res = run(project, "-n", env={"XDG_CACHE_HOME": str(tmp_path / "cache")})
    if "expected str instance, LocalSourceFile found" in res.stdout + res.stderr:
        raise KnownSnakemakeBug((res.stdout + res.stderr)[-500:])
    assert job_counts(res) == repository_plan


def _same_file(a: Path, b: Path) -> bool:
    """Equal files; Parquet tables equal with their metadata but a recorded duration (`seconds`)."""
    if a.suffix != ".parquet":
        return a.read_bytes() == b.read_bytes()
    ta, tb = pq.read_table(a), pq.read_table(b)

    def meta(t):
        m = {k: v for k, v in (t.schema.metadata or {}).items() if k != b"flatlandia"}
        own = json.loads((t.schema.metadata or {}).get(b"flatlandia", b"{}"))
        return m, {k: v for k, v in own.items() if k != "seconds"}

    return ta.equals(tb) and meta(ta) == meta(tb)


@pytest.mark.slow
def test_a_module_from_a_tag_runs_maps_as_the_repository_does(github_project, default_run):
    """`maps` of the tiny scene in the user's project: the same files as the repository's own run; the
    module's onstart removes a killed run's temporary, its onsuccess writes the run summary, and the
    provenance records name the release the rules came from."""
    project, env = github_project
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = project / "results" / f".x.parquet.partial-{files._host_tag()}-{dead.pid}-abcdefgh"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"left by a killed run")
    res = run(project, "--cores", "2", "maps", env=env)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    assert not stale.exists()
    assert (project / "results" / "summary.md").is_file() and "# Run summary" in res.stdout
    built = sorted(p.relative_to(project) for p in (project / "results").rglob("*") if p.is_file())
    assert Path(f"results/{TINY_SCENE}/queries/queries.parquet") in built, built
    for rel in built:
        if rel.name != "summary.md":
            assert _same_file(project / rel, default_run / rel), rel
    record = json.loads((project / "logs" / "provenance" / "queries" / f"scene-{TINY_SCENE}.json").read_text())
    assert record["package_version"] == __version__
    assert GITHUB_REPO in record["workflow"]["source"] and TAG in record["git_commit"], record["workflow"]


# ---------------------------------------------------------------- lint


@pytest.mark.slow
def test_a_bare_clone_plans_and_lints_cleanly(tmp_path):
    """A clone with no ../shared beside it: the plan starts with the download, and --lint is clean."""
    clone = copy_checkout(tmp_path / "clone")
    res = run(clone, "-n")
    counts = job_counts(res)
    assert counts["fetch_flatlandia"] == 1 and counts["all"] == 1, counts
    res = run(clone, "--lint")
    assert res.returncode == 0 and "Congratulations" in res.stderr, (res.stdout + res.stderr)[-3000:]


@pytest.mark.slow  # the published data (flat_root)
def test_lint_is_clean_with_the_published_data(flat_root, tmp_path):
    res = run(REPO, "--lint", "-d", str(tmp_path), "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0 and "Congratulations" in res.stderr, (res.stdout + res.stderr)[-3000:]
