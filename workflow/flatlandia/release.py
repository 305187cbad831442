"""The release: one version, ``[project] version`` of pyproject.toml, which the package
(``flatlandia.__version__``), ``flatlandia --version``, the provenance records and the report show.

Why read it rather than write it twice: a clone (installed or not) reads its own pyproject.toml, an
installed wheel its distribution's metadata, which the build took from the same line. The workflow
checks that the package its rules import has its own version (:func:`workflow_package_mismatch`):
a module deployed from a tag imports whatever flatlandia is installed.
"""

from __future__ import annotations

import tomllib
from importlib import metadata
from pathlib import Path

#: pyproject.toml of the clone this package sits in (workflow/flatlandia/ -> the repository root)
PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def pyproject_version(path: str | Path) -> str | None:
    """The version in the pyproject.toml at ``path`` when it is flatlandia's, else None."""
    try:
        project = tomllib.loads(Path(path).read_text()).get("project", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    if project.get("name") != "flatlandia" or "version" not in project:
        return None
    return str(project["version"])


def package_version() -> str:
    """This package's version: its clone's pyproject.toml, else the installed distribution's."""
    found = pyproject_version(PYPROJECT)
    if found:
        return found
    try:
        return metadata.version("flatlandia")
    except metadata.PackageNotFoundError:
        return "unknown"


def workflow_package_mismatch(pyproject: str | Path) -> str:
    """'' when the workflow whose pyproject.toml is ``pyproject`` has this package's version, else
    the problem and what to install (an unreadable pyproject.toml is not checked)."""
    wanted = pyproject_version(pyproject)
    have = package_version()
    if wanted is None or wanted == have:
        return ""
    return (
        f"the workflow is flatlandia {wanted}, but its rules would import the Python package flatlandia {have} "
        f"({Path(__file__).resolve().parent}): install the package of the same release, "
        f"pip install 'flatlandia[workflow] @ git+<repository>@v{wanted}' (docs/usage.md, 'Use it from your own workflow')"
    )
