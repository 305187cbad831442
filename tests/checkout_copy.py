"""This checkout as a user gets it: its files (tracked, and new ones git does not ignore: the working
tree under test), copied with their links, optionally committed as a git repository with a release
tag. Used by the deployment tests (a module from a tag, a bare clone) and the wheel's test."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from conftest import REPO

from flatlandia import release

#: the release tag of this checkout: v<pyproject.toml's version>
TAG = f"v{release.pyproject_version(REPO / 'pyproject.toml')}"


def git(folder: Path, *args: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}
    res = subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True, env=env, timeout=60)
    assert res.returncode == 0, (args, res.stderr)
    return res.stdout


def copy_checkout(dest: Path) -> Path:
    """Copy the checkout's files (no results, no venv, nothing ignored) into ``dest``."""
    names = git(REPO, "ls-files", "-z", "--cached", "--others", "--exclude-standard").split("\0")
    for name in filter(None, names):
        src = REPO / name
        if not os.path.lexists(src):  # deleted in the working tree, not yet committed
            continue
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target, follow_symlinks=False)
    return dest


def tagged_repository(dest: Path, tag: str = TAG, edit=None) -> Path:
    """The checkout as a git repository at ``dest`` whose one commit carries ``tag``; ``edit(dest)``
    changes the files before the commit."""
    copy_checkout(dest)
    if edit is not None:
        edit(dest)
    git(dest, "init", "-q")
    git(dest, "add", "-A")
    git(dest, "-c", "user.name=test", "-c", "user.email=test@example.org", "commit", "-q", "-m", "release")
    git(dest, "tag", tag)
    return dest
