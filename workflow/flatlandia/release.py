"""The release: one version, ``[project] version`` of pyproject.toml, which the package
(``flatlandia.__version__``), ``flatlandia --version``, the provenance records and the report show.

Why read it rather than write it twice: a clone (installed or not) reads its own pyproject.toml, an
installed wheel its distribution's metadata, which the build took from the same line. The workflow
checks that the package its rules import has its own version (:func:`workflow_package_mismatch`):
a module deployed from a tag imports whatever flatlandia is installed.

The repository's address is written once too, ``[project.urls] Repository`` of pyproject.toml, once
it is published (:func:`repository`); the docs' install and deploy commands name it
``$FLATLANDIA_REPO`` (docs/deployment.md, "The repository's address"), and an install command this
package prints names the module's own source when it runs as one (:func:`install_command`).
"""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path
from urllib.parse import unquote

#: pyproject.toml of the clone this package sits in (workflow/flatlandia/ -> the repository root)
PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"
#: the shell variable the docs' install and deploy commands name the repository by
REPOSITORY_VARIABLE = "FLATLANDIA_REPO"
#: a module's remote source as Snakemake names its folder: GitHub's raw files
#: (raw.githubusercontent.com/OWNER/NAME/REF/..., HOST/OWNER/NAME/raw/REF/... on another host) and
#: GitLab's files API (HOST/api/v4/projects/OWNER%2FNAME/repository/files/...?ref=REF)
_SOURCES = (
    (re.compile(r"^https://raw\.githubusercontent\.com/(?P<repo>[^/]+/[^/]+)/(?P<ref>[^/]+)/"), "github.com"),
    (re.compile(r"^https://(?P<host>[^/@]+)/(?P<repo>[^/]+/[^/]+)/raw/(?P<ref>[^/]+)/"), None),
    (
        re.compile(
            r"^https://(?P<host>[^/@]+)/api/v4/projects/(?P<repo>[^/]+)/repository/files/[^?]*\?ref=(?P<ref>[^&]+)"
        ),
        None,
    ),
)


def _project(path: str | Path) -> dict:
    """The ``[project]`` table of the pyproject.toml at ``path`` when it is flatlandia's, else {}."""
    try:
        project = tomllib.loads(Path(path).read_text()).get("project", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return {}
    return project if project.get("name") == "flatlandia" else {}


def pyproject_version(path: str | Path) -> str | None:
    """The version in the pyproject.toml at ``path`` when it is flatlandia's, else None."""
    project = _project(path)
    return str(project["version"]) if "version" in project else None


def repository(path: str | Path = PYPROJECT) -> str | None:
    """The published repository's address, ``[project.urls] Repository``: of the pyproject.toml at
    ``path`` (this package's clone), else of the installed distribution's metadata; None while the
    repository is not published."""
    project = _project(path)
    if project:
        return str(project.get("urls", {}).get("Repository", "")).strip() or None
    try:
        urls = metadata.metadata("flatlandia").get_all("Project-URL") or []
    except metadata.PackageNotFoundError:
        return None
    for entry in urls:
        label, _, url = entry.partition(",")
        if label.strip().lower() == "repository" and url.strip():
            return url.strip()
    return None


def module_source(source: str) -> tuple[str, str] | None:
    """(repository address, ref) of a module loaded from a remote source, from the address
    Snakemake gives its folder (``github(...)``, ``gitlab(...)``); None for a folder or another form."""
    for pattern, host in _SOURCES:
        m = pattern.match(source)
        if m:
            repo = unquote(m["repo"])
            return f"https://{host or m['host']}/{repo}", unquote(m["ref"])
    return None


def install_command(version: str, source: str | None = None) -> str:
    """The pip command that installs the package of the workflow's release ``version``: from the
    module's own source and ref when it runs as one, else from the published repository at tag
    v<version>, else from ``$FLATLANDIA_REPO`` (the address the user deployed from)."""
    found = module_source(source) if source else None
    repo, ref = found if found else (repository() or f"${REPOSITORY_VARIABLE}", f"v{version}")
    return f"pip install 'flatlandia[workflow] @ git+{repo}@{ref}'"


def package_version() -> str:
    """This package's version: its clone's pyproject.toml, else the installed distribution's."""
    found = pyproject_version(PYPROJECT)
    if found:
        return found
    try:
        return metadata.version("flatlandia")
    except metadata.PackageNotFoundError:
        return "unknown"


def workflow_package_mismatch(pyproject: str | Path, source: str | None = None) -> str:
    """'' when the workflow whose pyproject.toml is ``pyproject`` has this package's version, else
    the problem and what to install (an unreadable pyproject.toml is not checked); ``source``: the
    workflow's folder as Snakemake names it (a remote module's address names what to install)."""
    wanted = pyproject_version(pyproject)
    have = package_version()
    if wanted is None or wanted == have:
        return ""
    return (
        f"the workflow is flatlandia {wanted}, but its rules would import the Python package flatlandia {have} "
        f"({Path(__file__).resolve().parent}): install the package of the same release, "
        f"{install_command(wanted, source)} (docs/usage.md, 'Use it from your own workflow')"
    )
