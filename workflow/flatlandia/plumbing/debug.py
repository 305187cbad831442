"""Run one rule's script outside Snakemake, in this process, for debugging.

:func:`mock_snakemake` parses the workflow (``workflow/Snakefile`` with the default config, then
any ``configfiles`` and ``config`` overrides, as ``snakemake --configfile/--config`` would), builds
the job of one rule for the given wildcards and returns the ``snakemake`` object its script would
receive: the job's resolved input, output, params, log, wildcards, threads, resources and config.
:func:`run_script` runs the rule's script with it in the working folder, in this interpreter, so
``breakpoint()``, a debugger's breakpoints and ``print`` work. From the shell::

    flatlandia debug reference_map scene=12 --config flatlandia_root=../shared/flatlandia

The idea is PyPSA-Eur's ``mock_snakemake`` (scripts/_helpers.py); this one asks Snakemake's own
job for its values, so input functions, params and thread limits come out as in a real run.
"""

from __future__ import annotations

import contextlib
import os
import runpy
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

SNAKEFILE = Path(__file__).resolve().parents[2] / "Snakefile"


class DebugError(Exception):
    """A rule, wildcard or input the debugger cannot use; the message says which."""


@contextlib.contextmanager
def _cwd(path: Path) -> Iterator[None]:
    back = Path.cwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(back)


def _script_path(rule) -> Path:
    """The rule's script as a path (Snakemake keeps it relative to the rule file's folder)."""
    script = Path(rule.script)
    if script.is_absolute():
        return script
    base = rule.basedir
    base = base.get_path_or_uri(secret_free=True) if hasattr(base, "get_path_or_uri") else str(base)
    return (Path(base) / script).resolve()


def mock_snakemake(
    rule: str,
    workdir: str | Path = ".",
    configfiles: Sequence[str | Path] = (),
    config: Mapping | None = None,
    snakefile: str | Path | None = None,
    cores: int = 1,
    **wildcards,
):
    """The ``snakemake`` object that rule ``rule``'s script receives for ``wildcards``.

    Paths in it are relative to ``workdir`` (the workflow's working folder, as in a real run);
    :func:`run_script` runs the script there. The object also carries ``script`` (the rule's
    script file) and ``workdir`` (absolute). ``cores`` caps the job's threads as ``--cores`` does.
    Raises :class:`DebugError` for an unknown rule, missing or unknown wildcards, or a rule
    without a script.
    """
    from snakemake.api import SnakemakeApi
    from snakemake.dag import DAG
    from snakemake.iocontainers import Snakemake
    from snakemake.jobs import Job
    from snakemake.settings.enums import Quietness
    from snakemake.settings.types import ConfigSettings, DAGSettings, OutputSettings, ResourceSettings

    workdir = Path(workdir).resolve()
    snakefile = Path(snakefile or SNAKEFILE).resolve()
    if not snakefile.is_file():
        raise DebugError(f"no workflow at {snakefile} (an installed package has none beside it): give --snakefile")
    wildcards = {k: str(v) for k, v in wildcards.items()}
    output = OutputSettings(enable_file_logging=False, quiet={Quietness.ALL})
    config_settings = ConfigSettings(config=dict(config or {}), configfiles=[Path(f) for f in configfiles])
    with _cwd(workdir), SnakemakeApi(output) as api:
        workflow_api = api.workflow(
            resource_settings=ResourceSettings(cores=int(cores)),
            config_settings=config_settings,
            snakefile=snakefile,
            workdir=workdir,
        )
        workflow = workflow_api._workflow  # the parsed workflow (no public accessor in Snakemake 9)
        workflow.dag_settings = DAGSettings()
        names = sorted(r.name for r in workflow.rules)
        if rule not in names:
            raise DebugError(f"no rule {rule!r} in {snakefile}; rules: {', '.join(names)}")
        r = workflow.get_rule(rule)
        if not r.script:
            raise DebugError(f"rule {rule} runs no script (only rules with `script:` can be debugged)")
        expected = set(r.wildcard_names)
        if set(wildcards) != expected:
            missing, unknown = sorted(expected - set(wildcards)), sorted(set(wildcards) - expected)
            raise DebugError(
                f"rule {rule} takes the wildcards {sorted(expected) or 'none'}"
                + (f"; missing {missing}" if missing else "")
                + (f"; unknown {unknown}" if unknown else "")
            )
        check_wildcards(r, wildcards)
        try:
            job = Job(r, DAG(workflow, rules=[r]), wildcards)
        except Exception as e:  # an input function refusing the job (InputFunctionException, WorkflowError)
            first = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
            raise DebugError(f"rule {rule} {_shown(wildcards)}: the job cannot be built: {first[:300]}") from None
        outside = [str(p) for p in [*job.output, *job.log] if not _inside(workdir, p)]
        if outside:
            raise DebugError(f"rule {rule} {_shown(wildcards)} would write outside {workdir}: {', '.join(outside[:3])}")
        smk = Snakemake(
            job.input,
            job.output,
            job.params,
            job.wildcards,
            job.threads,
            job.resources,
            job.log,
            workflow.config,
            r.name,
            None,
        )
    smk.script = _script_path(r)
    smk.scriptdir = str(smk.script.parent)
    smk.workdir = workdir
    return smk


def _shown(wildcards: Mapping) -> str:
    return " ".join(f"{k}={str(v)[:60]!r}" for k, v in wildcards.items()) or "(no wildcards)"


def _inside(workdir: Path, path) -> bool:
    """Whether ``path`` (relative to the working folder) stays inside it once resolved."""
    try:
        return (workdir / str(path)).resolve().is_relative_to(workdir.resolve())
    except (OSError, RuntimeError):
        return False


def check_wildcards(rule, wildcards: Mapping[str, str]) -> None:
    """Refuse (DebugError) wildcard values a real run could never give the rule: a value that is not
    one plain name (:func:`flatlandia.plumbing.names.name_problem`: ``../../x`` would write elsewhere) or one
    outside the rule's ``wildcard_constraints`` and the workflow's (an unknown scene, a region the
    rule does not build), checked as Snakemake matches a target against the rule's outputs."""
    from flatlandia.plumbing.names import name_problem

    for key, value in wildcards.items():
        why = name_problem(value)
        if why:
            raise DebugError(f"wildcard {key}={str(value)[:80]!r} is refused: {why} (a wildcard is one plain name)")
    for f in [*rule.output, *rule.log]:
        names = f.get_wildcard_names()
        if not names:
            continue
        given = {k: wildcards[k] for k in names if k in wildcards}
        if set(given) != set(names):
            continue
        m = f.match(f.apply_wildcards(given))
        bad = sorted(k for k in names if m is None or m.group(k) != given[k])
        if bad:
            k = bad[0]
            constraint = f.wildcard_constraints().get(k)
            allowed = constraint.pattern if constraint is not None else ".+"
            allowed = allowed if len(allowed) <= 200 else allowed[:197] + "..."
            raise DebugError(
                f"wildcard {k}={given[k][:80]!r} is not one rule {rule.name} takes: it must match {allowed!r} "
                f"(the rule's and the workflow's wildcard_constraints; for a scene, an id of the scene sheet)"
            )


def missing_inputs(smk) -> list[str]:
    """The job's inputs that are not there (relative to its working folder)."""
    return [str(p) for p in smk.input if not (Path(smk.workdir) / p).exists()]


def run_script(smk, log_to_terminal: bool = False) -> None:
    """Run the rule's script with ``smk`` (from :func:`mock_snakemake`) in this process.

    As Snakemake does, the folders of the outputs and the log are made first and the script runs in
    the working folder. ``log_to_terminal`` drops the rule's log file: the script logs to stderr.
    Raises :class:`DebugError` when an input is missing (build it first with snakemake).
    """
    missing = missing_inputs(smk)
    if missing:
        raise DebugError(
            f"rule {smk.rule}: missing input(s) {missing} in {smk.workdir}: build them first, e.g. "
            f"`snakemake --cores 1 {' '.join(missing[:3])}`"
        )
    if log_to_terminal:
        smk.log = type(smk.log)()  # an empty Snakemake Log: rule_log.setup logs to stderr
    with _cwd(Path(smk.workdir)):
        for p in [*smk.output, *smk.log]:
            Path(p).parent.mkdir(parents=True, exist_ok=True)
        runpy.run_path(str(smk.script), init_globals={"snakemake": smk}, run_name="__main__")


def describe(smk) -> str:
    """The job as the script sees it: one line per input, output, param, log and wildcard."""

    def items(container) -> list[tuple[str, object]]:
        out, covered = list(container.items()), set()
        for start, end in container._names.values():  # Snakemake's named slices of the list
            covered.update(range(start, start + 1 if end is None else end))
        return out + [(str(i), v) for i, v in enumerate(container) if i not in covered]

    lines = [f"rule {smk.rule}: {smk.script}", f"  working folder: {smk.workdir}", f"  threads: {smk.threads}"]
    for title, container in (
        ("wildcards", smk.wildcards),
        ("input", smk.input),
        ("output", smk.output),
        ("log", smk.log),
        ("params", smk.params),
    ):
        lines.append(f"  {title}:")
        if title == "log" and not len(container):
            lines.append("    (none: the script logs to stderr)")
        for k, v in items(container):
            text = repr(v)
            lines.append(f"    {k}: {text if len(text) <= 200 else text[:197] + '...'}")
    return "\n".join(lines)
