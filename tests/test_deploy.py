"""Deploying the workflow the ways Snakemake users do (issue 35): `snakemake` from the repository root
(the default target `all`, the report), the workflow as a module of a user's own project loaded
from its repository at a release tag (deployed by `snakedeploy deploy-workflow URL DEST --tag vX`
itself, which writes `github(...)`; offline here: git's url.<base>.insteadOf points github.com at a
tagged copy of this checkout), with the module's handlers and the project's own relative paths
(issue 45), `snakemake --lint` in a bare clone and with the data, and explicit configuration over
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
#: snakedeploy, as `make install` puts it beside Snakemake (envs/requirements-dev.txt)
SNAKEDEPLOY = str(Path(SNAKEMAKE).parent / "snakedeploy")
#: the line that starts each planned download's note (flatlandia.data.fetch.download_note)
DOWNLOAD = "flatlandia: this plan downloads "
#: lines a project's Snakefile may add: the module's handlers called by hand (what the docs asked for
#: before issue 45), and an onsuccess of its own
OLD_HANDLER_LINES = """

onstart:
    flatlandia_workflow.onstart()


onsuccess:
    flatlandia_workflow.onsuccess()
    print("the project's own onsuccess")
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


def deploy(folder: Path, tag: str, env: dict, source: str | None = None) -> Path:
    """A user's project as `snakedeploy deploy-workflow https://github.com/<GITHUB_REPO> FOLDER --tag
    TAG` writes it (config/, profiles/ and LICENSE copied, workflow/Snakefile loading the module), from
    the tagged copy ``env`` serves; ``source`` replaces the module's `github(...)` source."""
    cmd = [SNAKEDEPLOY, "deploy-workflow", f"https://github.com/{GITHUB_REPO}", str(folder), "--tag", tag]
    res = subprocess.run([*cmd, "--name", "flatlandia_workflow"], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    snakefile = folder / "workflow" / "Snakefile"
    written = f'github("{GITHUB_REPO}", path="workflow/Snakefile", tag="{tag}")'
    assert written in snakefile.read_text() and "onstart" not in snakefile.read_text()
    if source is not None:
        snakefile.write_text(snakefile.read_text().replace(written, source))
    return folder


def own_config(project: Path, **changes) -> Path:
    """The project's config/config.yaml changed: by default, the defaults on the tiny scene."""
    config = project / "config" / "config.yaml"
    own = yaml.safe_load(config.read_text())
    own.update(
        changes or dict(flatlandia_root=str(TINY_ROOT), scenes=str(REPO / "config" / "test" / "tiny_scenes.tsv"))
    )
    config.write_text(yaml.safe_dump(own, sort_keys=False))
    return project


def downloads(res: subprocess.CompletedProcess) -> list[str]:
    """The planned downloads' notes of a run or dry run."""
    return [line for line in (res.stdout + res.stderr).splitlines() if line.startswith(DOWNLOAD)]


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
    env = github_env(release_repository, tmp_path / "cache")
    return own_config(deploy(tmp_path / "project", TAG, env)), env


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
    for part in DOCUTILS_PARTS:  # the landing page showed report metadata as docutils' parts (issue 45)
        assert part not in html, part


#: what Snakemake 9.27's landing page showed of a report metadata value: docutils' publish_parts
#: (WHOLE, ENCODING utf-8, ERRORS strict, VERSION of docutils)
DOCUTILS_PARTS = ('"whole":', '"encoding": "utf-8"', '"errors": "strict"', "<document source=")


def test_the_reports_landing_page_is_the_workflows_description():
    """The landing page is the workflow's description (workflow/report/workflow.rst, Snakemake's
    `report:`), which names the release; no report metadata, which Snakemake 9.27 shows as docutils'
    parts. Rendered as Snakemake renders it (Jinja, then docutils' html_body)."""
    import docutils
    from docutils.core import publish_parts
    from jinja2 import Environment

    profile = yaml.safe_load((REPO / "workflow" / "profiles" / "default" / "config.yaml").read_text())
    assert not any(k.startswith("report-metadata") for k in profile)
    assert 'report: "report/workflow.rst"' in (REPO / "workflow" / "Snakefile").read_text()
    text = Environment(trim_blocks=True, lstrip_blocks=True).from_string(
        (REPO / "workflow" / "report" / "workflow.rst").read_text()
    )
    html = publish_parts(text.render(snakemake=None, categories={}, files=[]), writer="html")["html_body"]
    assert f"Flatlandia workflow, flatlandia {__version__}." in html
    assert "System Message" not in html  # docutils' own errors would show on the page
    for part in (*DOCUTILS_PARTS, f'"version": "{docutils.__version__}"', "ENCODING"):
        assert part not in html, part


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
    env = github_env(repository, tmp_path / "cache")
    res = run(own_config(deploy(tmp_path / "project", "v99.0.0", env)), "-n", env=env)
    assert res.returncode != 0
    errors = [line for line in (res.stdout + res.stderr).splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and "flatlandia 99.0.0" in errors[0] and f"flatlandia {__version__}" in errors[0], errors
    # what to install, from the module's own source and tag
    assert f"pip install 'flatlandia[workflow] @ git+https://github.com/{GITHUB_REPO}@v99.0.0'" in errors[0], errors
    assert "Traceback" not in res.stderr


@pytest.mark.slow
def test_a_module_without_the_package_names_what_to_install(github_project, tmp_path):
    """The rules import the package, which a module does not bring: one line with the pip command."""
    project, env = github_project
    absent = tmp_path / "absent" / "flatlandia"  # first on the path: `import flatlandia` fails
    absent.mkdir(parents=True)
    (absent / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'flatlandia'\", name='flatlandia')\n"
    )
    res = run(project, "-n", env=env | {"PYTHONPATH": str(absent.parent)})
    assert res.returncode != 0
    errors = [line for line in (res.stdout + res.stderr).splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and errors[0].startswith("ERROR: the Python package flatlandia is not installed"), errors
    assert f"pip install 'flatlandia[workflow] @ git+https://github.com/{GITHUB_REPO}@{TAG}'" in errors[0], errors
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
    env = github_env(release_repository, tmp_path / "cache")
    project = own_config(deploy(tmp_path / "project", TAG, env, source=source))
    res = run(project, "-n", env={"XDG_CACHE_HOME": str(tmp_path / "cache")})
    if "expected str instance, LocalSourceFile found" in res.stdout + res.stderr:
        raise KnownSnakemakeBug((res.stdout + res.stderr)[-500:])
    assert job_counts(res) == repository_plan


def _same_file(a: Path, b: Path) -> bool:
    """Equal files; Parquet tables equal with their metadata but a recorded duration (`seconds`); the
    ingest report but the data folder as each run names it (`root`: the project's config gives it
    absolute, the repository's run relative to its run folder, flatlandia.plumbing.travel)."""
    if a.name == "ingest.json":
        ja, jb = json.loads(a.read_text()), json.loads(b.read_text())
        return {k: v for k, v in ja.items() if k != "root"} == {k: v for k, v in jb.items() if k != "root"}
    if a.suffix != ".parquet":
        return a.read_bytes() == b.read_bytes()
    ta, tb = pq.read_table(a), pq.read_table(b)

    def meta(t):
        m = {k: v for k, v in (t.schema.metadata or {}).items() if k != b"flatlandia"}
        own = json.loads((t.schema.metadata or {}).get(b"flatlandia", b"{}"))
        return m, {k: v for k, v in own.items() if k != "seconds"}

    return ta.equals(tb) and meta(ta) == meta(tb)


def killed_runs_temporary(project: Path) -> Path:
    """A temporary left in the project's results/ by a run whose process is gone."""
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = project / "results" / f".x.parquet.partial-{files._host_tag()}-{dead.pid}-abcdefgh"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"left by a killed run")
    return stale


@pytest.mark.slow
def test_a_module_from_a_tag_runs_maps_as_the_repository_does(github_project, default_run):
    """`maps` of the tiny scene in the user's project, its Snakefile as snakedeploy wrote it: the same
    files as the repository's own run; the module's onstart removes a killed run's temporary, its
    onsuccess writes the run summary (no line added by hand), and the provenance records name the
    release the rules came from."""
    project, env = github_project
    stale = killed_runs_temporary(project)
    res = run(project, "--cores", "2", "maps", env=env)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    assert not stale.exists()
    assert (project / "results" / "summary.md").is_file() and res.stdout.count("# Run summary") == 1
    assert "add to your workflow/Snakefile" not in res.stderr
    built = sorted(p.relative_to(project) for p in (project / "results").rglob("*") if p.is_file())
    assert Path(f"results/{TINY_SCENE}/queries/queries.parquet") in built, built
    for rel in built:
        if rel.name != "summary.md":
            assert _same_file(project / rel, default_run / rel), rel
    record = json.loads((project / "logs" / "provenance" / "queries" / f"scene-{TINY_SCENE}.json").read_text())
    assert record["package_version"] == __version__
    assert GITHUB_REPO in record["workflow"]["source"] and TAG in record["git_commit"], record["workflow"]


@pytest.mark.slow
def test_a_project_that_calls_the_module_handlers_itself_runs_them_once(github_project):
    """A Snakefile with the lines the docs asked for before, and an onsuccess of its own: each of the
    module's handlers runs once, the project's too."""
    project, env = github_project
    snakefile = project / "workflow" / "Snakefile"
    snakefile.write_text(snakefile.read_text() + OLD_HANDLER_LINES)
    stale = killed_runs_temporary(project)
    res = run(project, "--cores", "1", f"results/{TINY_SCENE}/ingest/ingest.json", env=env)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    assert not stale.exists() and res.stderr.count("the leftover of an interrupted run") == 1, res.stderr[-2000:]
    assert res.stdout.count("# Run summary") == 1 and res.stdout.count("the project's own onsuccess") == 1
    assert (project / "results" / "summary.md").is_file()


@pytest.mark.slow
def test_a_deployed_projects_copied_config_says_what_its_plan_downloads(release_repository, tmp_path):
    """The config snakedeploy copies names the data as ../shared/flatlandia and the Lund photos as
    ../shared/images/lund, relative to the project, where neither exists: the dry run plans both
    downloads and says so, one line each (what, the rule, from where, into where, the size, why)."""
    env = github_env(release_repository, tmp_path / "cache")
    project = deploy(tmp_path / "project", TAG, env)
    res = run(project, "-n", env=env)
    counts = job_counts(res)
    assert counts["fetch_flatlandia"] == 1 and counts["fetch_images"] == 1, counts
    photos, published = sorted(downloads(res))
    assert published.startswith(f"{DOWNLOAD}the published data (rule fetch_flatlandia): https://codeload.github.com/")
    assert " into resources/flatlandia, size unknown until it starts, at most 1024 MB" in published, published
    assert (
        f"flatlandia_root '../shared/flatlandia' does not exist here ({tmp_path / 'shared' / 'flatlandia'})"
        in published
    )
    assert photos.startswith(f"{DOWNLOAD}the photos of images scene lund (rule fetch_images): https://"), photos
    assert f"its path '../shared/images/lund' does not exist here ({tmp_path / 'shared' / 'images' / 'lund'})" in photos


@pytest.mark.slow
@pytest.mark.parametrize("source", ["github", "folder"])
def test_a_deployed_projects_relative_paths_are_its_own(source, tmp_path):
    """Relative paths of the project's config are taken from the project, never from the module's
    repository, even one loaded from a folder that holds them: a data folder `data` there only is
    fetched (and said so); copied into the project, it is read from there, as written."""
    repository = tagged_repository(tmp_path / "remote" / "flatlandia-workflow")
    shutil.copytree(TINY_ROOT, repository / "data")  # beside the module's own files only
    env = github_env(repository, tmp_path / "cache")
    folder = f'"{repository / "workflow" / "Snakefile"}"' if source == "folder" else None
    project = deploy(tmp_path / "project", TAG, env, source=folder)
    shutil.copy(REPO / "config" / "test" / "tiny_scenes.tsv", project / "config" / "tiny_scenes.tsv")
    own_config(project, flatlandia_root="data", scenes="config/tiny_scenes.tsv")
    res = run(project, "-n", "maps", env=env)
    assert job_counts(res)["fetch_flatlandia"] == 1
    (note,) = downloads(res)
    assert f"flatlandia_root 'data' does not exist here ({project / 'data'})" in note, note
    shutil.copytree(TINY_ROOT, project / "data")
    res = run(project, "-n", "maps", env=env)
    counts = job_counts(res)
    assert "fetch_flatlandia" not in counts and counts["ingest"] == 1, counts
    assert "data/local_maps.json" in res.stdout and str(repository) not in res.stdout and not downloads(res)


# ---------------------------------------------------------------- lint


@pytest.mark.slow
def test_a_bare_clone_plans_and_lints_cleanly(tmp_path):
    """A clone with no ../shared beside it: the plan starts with the download, and --lint is clean."""
    clone = copy_checkout(tmp_path / "clone")
    res = run(clone, "-n")
    counts = job_counts(res)
    assert counts["fetch_flatlandia"] == 1 and counts["all"] == 1, counts
    assert len(downloads(res)) == counts["fetch_flatlandia"] + counts.get("fetch_images", 0)  # one line each
    res = run(clone, "--lint")
    assert res.returncode == 0 and "Congratulations" in res.stderr, (res.stdout + res.stderr)[-3000:]


@pytest.mark.slow  # the published data (flat_root)
def test_lint_is_clean_with_the_published_data(flat_root, tmp_path):
    res = run(REPO, "--lint", "-d", str(tmp_path), "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0 and "Congratulations" in res.stderr, (res.stdout + res.stderr)[-3000:]
