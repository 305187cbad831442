"""The workflow's ``onstart`` and ``onsuccess`` run when it is a module of another project.

Why: Snakemake (9.x, read on 9.27.1) runs only the main Snakefile's handlers: ``Workflow.onstart``
registers a handler only for the main Snakefile and leaves a module's in the module's namespace. A
project deployed with ``snakedeploy deploy-workflow`` (``use rule * from flatlandia_workflow``)
would lose the run's start (a killed run's temporaries removed, the rerun notice) and its summary
(``results/summary.md``) unless its Snakefile called them by hand.

:func:`carry`, called by the workflow's Snakefile when it is read as a module, makes them the run's:
after the project's own handler when its Snakefile registers one (before or after its ``use rule``),
alone otherwise; each runs at most once, so a project whose handler also calls them
(``flatlandia_workflow.onstart()``, the lines the docs gave before) runs them once. Should
Snakemake change what this relies on (the handler slots ``_onstart``, ``_onsuccess`` and the
registering methods), nothing is carried: :func:`carry` returns False and the Snakefile prints
:func:`lines_to_add`, the lines the project's Snakefile then needs.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, MutableMapping

#: the handlers carried, by the name Snakemake registers them under
HANDLERS = ("onstart", "onsuccess")


def as_module(workflow) -> bool:
    """Whether the Snakefile being read is a module of another project's Snakefile (not the main
    one, nor a file the main one includes)."""
    modifier = getattr(workflow, "modifier", None)
    is_main = getattr(modifier, "is_main_snakefile", None)
    return callable(is_main) and not is_main()


def module_name(workflow) -> str:
    """The name the project's Snakefile gave the module (``module flatlandia_workflow:``)."""
    return getattr(getattr(workflow, "modifier", None), "namespace", None) or "flatlandia_workflow"


def _once(handler: Callable[[], object]) -> Callable[..., object]:
    """``handler`` run at most once, whoever calls it (the run, or the project's own handler)."""
    done = []

    @functools.wraps(handler)
    def run(*_args, **_kwargs):
        if not done:
            done.append(True)
            return handler()
        return None

    return run


def _after(theirs: Callable, ours: Callable) -> Callable:
    """The run's handler: the one registered so far (the project's, or Snakemake's no-op), then ours."""

    def handler(log):
        theirs(log)
        ours()

    handler._flatlandia_carries = True
    return handler


def carry(workflow, namespace: MutableMapping) -> bool:
    """Register the module's handlers (``namespace["onstart"]``, ``["onsuccess"]``, as its Snakefile
    left them) as the run's, and put their run-once forms in ``namespace`` (what the project reaches
    as ``flatlandia_workflow.onstart()``). False, with nothing changed, when Snakemake's handler
    slots or registering methods are not there."""
    kind = type(workflow)
    if not all(
        callable(getattr(workflow, f"_{name}", None)) and callable(getattr(kind, name, None)) and name in namespace
        for name in HANDLERS
    ):
        return False
    for name in HANDLERS:
        slot, register, ours = f"_{name}", getattr(kind, name), _once(namespace[name])
        namespace[name] = ours
        setattr(workflow, slot, _after(getattr(workflow, slot), ours))

        def registering(func, register=register, slot=slot, ours=ours):
            """Snakemake's registration, then ours again after a handler of the main Snakefile."""
            out = register(workflow, func)
            current = getattr(workflow, slot)
            if not getattr(current, "_flatlandia_carries", False):
                setattr(workflow, slot, _after(current, ours))
            return out

        setattr(workflow, name, registering)
    return True


def lines_to_add(name: str) -> str:
    """What the project's Snakefile needs when :func:`carry` could not carry the handlers."""
    return (
        f"flatlandia: this Snakemake does not run a module's onstart/onsuccess (a killed run's temporaries "
        f"removed, the run summary); add to your workflow/Snakefile:\n\n"
        f"onstart:\n    {name}.onstart()\n\n\nonsuccess:\n    {name}.onsuccess()\n"
    )
