"""``flatlandia config``: check (or ``--write``) config/config.yaml and config/README.md, the files
generated from the config schema (:func:`flatlandia.config.generated_files`)."""

from __future__ import annotations

from pathlib import Path

from flatlandia import config, release
from flatlandia.commands.messages import error


def config_files(args) -> int:
    """Rewrite (``--write``) or check config/config.yaml and config/README.md against the schema."""
    if release.pyproject_version(Path(args.repo) / "pyproject.toml") is None:
        error(f"{args.repo} is not a clone of the workflow (no flatlandia pyproject.toml): give --repo")
        return 1
    stale, fresh = [], []
    for path, text in config.generated_files(Path(args.repo)).items():
        if path.exists() and path.read_text() == text:
            fresh.append(str(path))
            continue
        if args.write:
            path.write_text(text)
            print(f"wrote {path}")
        else:
            stale.append(str(path))
    if stale:
        error(f"{', '.join(stale)} out of date with {config.SCHEMA_PATH}: run `flatlandia config --write`")
        return 1
    if fresh:  # a check that passes says so (it printed nothing)
        print(f"{', '.join(fresh)}: up to date with {config.SCHEMA_PATH}")
    return 0
