"""A command's ``--out`` (and ``--plot``): refused before any work where it would replace one of the
command's inputs or a file the run's records name, and written whole, a failed write being one
``ERROR:`` line (``localize`` and ``score`` share it)."""

from __future__ import annotations

from pathlib import Path

from flatlandia.commands.messages import error
from flatlandia.plumbing import files, provenance
from flatlandia.plumbing.errors import InputError


def run_artifacts() -> dict[str, str]:
    """Every file the run's provenance records name -> the rule that made it ('' for a file the
    rules only read): what a command's --out must never replace."""
    made: dict[str, str] = {}
    for r in provenance.records():
        for a in r["inputs"]:
            made.setdefault(a, "")
        for a in r["outputs"]:
            made[a] = r["rule"]
    return made


def refuse_overwriting(out: str, inputs: list, kind: str = "file") -> Path:
    """The resolved --out, or an InputError naming --out when the write door refuses it
    (:func:`flatlandia.plumbing.files.check_target`): one of the command's own inputs (or an existing
    file in a folder it reads), an artifact recorded by the run in this folder (its queries, maps,
    export), a link, a device, a folder in the way, a dot-folder, Python's or the source tree's
    folders; all compared resolved (``results/../results/x`` and links are caught). Checked before
    any work, and again by the writer."""
    try:
        return files.check_target(out, reads=[p for p in inputs if p], artifacts=run_artifacts(), kind=kind)
    except InputError as e:
        raise InputError("--out", f"{out} {e.problem}") from None


def write_out(write, out: str, flag: str = "--out") -> bool:
    """Run ``write()``, a command's write of --out (or of ``flag``'s file); False after one ERROR line
    when the write door refused it or the write failed (a full disk, a folder in the way): nothing
    half-written is kept."""
    try:
        write()
    except InputError as e:
        error(f"{flag}: {e.path} {e.problem}")  # the door names the file or a file below it
        return False
    except OSError as e:
        full = files.full_disk_error(e)
        why = files.FULL_ERRNOS[full.errno] if full is not None else (e.strerror or str(e))
        error(f"{flag}: could not write {out}: {why}; nothing was written (free some space or give another {flag})")
        return False
    return True
