"""The repository's address in the docs (issue 45): every install and deploy command names it as
``$FLATLANDIA_REPO``, one variable documented in one place (docs/deployment.md, "The repository's
address"), whose value, once published, is ``[project.urls] Repository`` of pyproject.toml and is
shown there; no doc holds an ``<owner>/<repo>`` placeholder. And the helpers behind the workflow's
own install lines (flatlandia.release) and its download notes (flatlandia.data.fetch)."""

from __future__ import annotations

import re
import shlex

import pytest
from conftest import REPO
from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name

from flatlandia import release
from flatlandia.data import fetch

DOCS = [
    REPO / "README.md",
    REPO / "CHANGELOG.md",
    REPO / "config" / "README.md",
    *sorted((REPO / "docs").glob("*.md")),
]
#: where the variable is documented, and the anchor the other docs link to
HOME = REPO / "docs" / "deployment.md"
ANCHOR = "deployment.md#the-repositorys-address"
VARIABLE = f"${release.REPOSITORY_VARIABLE}"
PLACEHOLDER = re.compile(r"<owner>|<repo>|git\+<")


def code(text: str) -> list[str]:
    """Every line of a fenced code block and every inline code span of a Markdown text."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif fenced:
            out.append(line)
        else:
            out += re.findall(r"`([^`\n]+)`", line)
    return out


def addresses(command: str) -> list[str]:
    """The repository addresses a command installs or deploys this workflow from: snakedeploy's
    source, a ``git+ADDRESS@`` requirement, and ``-`` for a ``flatlandia`` requirement with none (a
    name on a package index, which this project is not published to)."""
    out = [m.strip("\"'") for m in re.findall(r"snakedeploy deploy-workflow\s+(\S+)", command)]
    if re.search(r"\bpip install\b", command):
        try:
            words = shlex.split(command.split("pip install", 1)[1].split("#", 1)[0])
        except ValueError:  # an unbalanced quote: a command cut by the prose
            words = command.split("pip install", 1)[1].split()
        for word in words:
            try:
                req = Requirement(word)
            except InvalidRequirement:  # a path (., dist/...whl) or an option
                continue
            if canonicalize_name(req.name) == "flatlandia":
                m = re.match(r"git\+(.+)@[^@]+$", req.url or "")
                out.append(m.group(1) if m else "-")
    else:
        out += re.findall(r"git\+([^@\s\"']+)@", command)
    return out


def allowed() -> set[str]:
    published = release.repository()
    return {VARIABLE} | ({published} if published else set())


def test_no_doc_holds_a_placeholder_address():
    """In the docs and the Snakefile; in the package's code, an install line's (its regular
    expressions name their groups in angle brackets)."""
    found = []
    package = sorted((REPO / "workflow" / "flatlandia").rglob("*.py"))
    for page in [*DOCS, REPO / "workflow" / "Snakefile", *package]:
        for i, line in enumerate(page.read_text().splitlines(), 1):
            if PLACEHOLDER.search(line) if page.suffix != ".py" else "git+<" in line:
                found.append(f"{page.relative_to(REPO)}:{i}: {line.strip()[:100]}")
    assert not found, found


def test_every_install_and_deploy_command_names_the_one_address():
    seen: dict[str, int] = {}
    wrong = []
    for page in DOCS:
        for command in code(page.read_text()):
            for address in addresses(command):
                seen[page.name] = seen.get(page.name, 0) + 1
                if address not in allowed():
                    wrong.append(f"{page.relative_to(REPO)}: {command.strip()[:120]}")
    assert not wrong, wrong
    # the README's two, usage.md's three, the CHANGELOG's two, deployment.md's (the checks see them)
    assert seen.get("README.md", 0) >= 2 and seen.get("usage.md", 0) >= 3 and seen.get("CHANGELOG.md", 0) >= 2, seen


def test_the_address_is_documented_once_and_shown_once_published():
    assignments = [
        (page, line) for page in DOCS for line in code(page.read_text()) if f"{release.REPOSITORY_VARIABLE}=" in line
    ]
    assert [page for page, _ in assignments] == [HOME], assignments
    assert "## The repository's address" in HOME.read_text()
    published = release.repository()
    if published:
        assert f"export {release.REPOSITORY_VARIABLE}={published}" in [line.strip() for _, line in assignments]
    for page in DOCS:
        text = page.read_text()
        if page != HOME and VARIABLE in text:
            assert ANCHOR in text or "The repository's address" in text, f"{page.relative_to(REPO)}: say where"


def test_the_checks_find_what_is_wrong():
    """The scanners themselves: placeholders, another address, a bare name, and what is fine."""
    text = (
        "`pip install flatlandia` and `pip install 'flatlandia[workflow] @ git+https://x.org/a/b@v1'`\n"
        "```bash\nsnakedeploy deploy-workflow https://github.com/a/b p --tag v1\n"
        'pip install "flatlandia @ git+$FLATLANDIA_REPO@v1" torch==2.13.0   # or\npip install -e .\n```\n'
    )
    found = [a for c in code(text) for a in addresses(c)]
    assert found == ["-", "https://x.org/a/b", "https://github.com/a/b", VARIABLE], found
    assert PLACEHOLDER.search("git+https://github.com/<owner>/<repo>@v1")


# ----------------------------------------------------------------------------- flatlandia.release


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("https://raw.githubusercontent.com/me/flat-wf/v0.1.0/workflow", ("https://github.com/me/flat-wf", "v0.1.0")),
        ("https://git.example.org/me/flat-wf/raw/v0.2.0/workflow", ("https://git.example.org/me/flat-wf", "v0.2.0")),
        (
            "https://gitlab.com/api/v4/projects/me%2Fflat-wf/repository/files/workflow/raw?ref=v1.0.0",
            ("https://gitlab.com/me/flat-wf", "v1.0.0"),
        ),
        ("/home/me/flat-wf/workflow", None),
    ],
)
def test_a_modules_source_names_its_repository_and_ref(source, expected):
    assert release.module_source(source) == expected


def test_the_install_command_names_the_module_else_the_one_address(tmp_path):
    source = "https://raw.githubusercontent.com/me/flat-wf/v0.3.0/workflow"
    assert (
        release.install_command("0.3.0", source)
        == "pip install 'flatlandia[workflow] @ git+https://github.com/me/flat-wf@v0.3.0'"
    )
    published = release.repository()
    where = published or VARIABLE
    assert release.install_command("0.3.0") == f"pip install 'flatlandia[workflow] @ git+{where}@v0.3.0'"
    # the address once written: [project.urls] Repository of a flatlandia pyproject.toml
    pyproject = tmp_path / "pyproject.toml"
    text = (REPO / "pyproject.toml").read_text()
    pyproject.write_text(text + '\n[project.urls]\nRepository = "https://example.org/flat/wf"\n')
    assert release.repository(pyproject) == "https://example.org/flat/wf"
    pyproject.write_text(text.replace('name = "flatlandia"', 'name = "other"', 1))
    assert release.repository(pyproject) != "https://example.org/flat/wf"


def test_a_mismatch_from_a_module_names_its_source(tmp_path):
    other = tmp_path / "pyproject.toml"
    version = release.package_version()
    other.write_text((REPO / "pyproject.toml").read_text().replace(f'version = "{version}"', 'version = "9.9.9"', 1))
    line = release.workflow_package_mismatch(other, "https://raw.githubusercontent.com/me/flat-wf/v9.9.9/workflow")
    assert "pip install 'flatlandia[workflow] @ git+https://github.com/me/flat-wf@v9.9.9'" in line, line
    assert "\n" not in line


# ----------------------------------------------------------------------------- download notes


def test_a_planned_download_is_one_line_with_its_size_when_known(tmp_path):
    archive = tmp_path / "data.zip"
    archive.write_bytes(b"x" * 2_500_000)
    line = fetch.download_note(
        "the published data", "fetch_flatlandia", archive.as_uri(), "resources/flatlandia", "why", 1024
    )
    assert line.startswith("this plan downloads the published data (rule fetch_flatlandia): file://")
    assert "into resources/flatlandia, 2.5 MB; why" in line
    line = fetch.download_note("x", "fetch_images", "https://example.org/a.zip\x1b[2J", "resources/images/a", "y", 50)
    assert "size unknown until it starts, at most 50 MB (fetch.max_download_mb)" in line
    assert "\x1b" not in line and "\\x1b" in line and "\n" not in line  # a sheet's url cannot draw on the terminal
