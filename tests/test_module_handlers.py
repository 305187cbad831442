"""A module's onstart/onsuccess carried into the project's run (flatlandia.plumbing.module_handlers),
on a stand-in of Snakemake's Workflow that registers handlers as Snakemake 9 does (the main
Snakefile's only); tests/test_deploy.py runs them in a deployed project with Snakemake itself."""

from __future__ import annotations

import inspect

import pytest

from flatlandia.plumbing import module_handlers


class Modifier:
    def __init__(self, main: bool):
        self.main, self.namespace = main, "flatlandia_workflow"

    def is_main_snakefile(self):
        return self.main


class Workflow:
    """What Snakemake's Workflow does with handlers: a slot each, set only by the main Snakefile."""

    def __init__(self):
        self._onstart = lambda log: None
        self._onsuccess = lambda log: None
        self.modifier = Modifier(main=False)  # reading the module

    def onstart(self, func):
        if self.modifier.is_main_snakefile():
            self._onstart = func

    def onsuccess(self, func):
        if self.modifier.is_main_snakefile():
            self._onsuccess = func


@pytest.fixture
def module():
    """(workflow, the module's namespace, what ran) after the module's Snakefile was read."""
    ran: list[str] = []
    workflow = Workflow()
    namespace = {"onstart": lambda: ran.append("ours start"), "onsuccess": lambda: ran.append("ours success")}
    assert module_handlers.as_module(workflow)
    assert module_handlers.carry(workflow, namespace)
    workflow.modifier = Modifier(main=True)  # back in the project's Snakefile
    return workflow, namespace, ran


def run(workflow):
    workflow._onstart("log")
    workflow._onsuccess("log")


def test_a_project_without_handlers_runs_the_modules(module):
    workflow, _, ran = module
    run(workflow)
    assert ran == ["ours start", "ours success"]


def test_a_project_handler_that_calls_the_modules_runs_them_once(module):
    """What the docs asked users to add before: `onstart: flatlandia_workflow.onstart()`."""
    workflow, namespace, ran = module
    workflow.onstart(lambda log: namespace["onstart"]())
    workflow.onsuccess(lambda log: (namespace["onsuccess"](), ran.append("theirs success")))
    run(workflow)
    assert ran == ["ours start", "ours success", "theirs success"]


def test_a_project_handler_of_its_own_runs_before_the_modules(module):
    workflow, _, ran = module
    workflow.onsuccess(lambda log: ran.append(f"theirs success {log}"))
    run(workflow)
    assert ran == ["ours start", "theirs success log", "ours success"]


def test_a_handler_the_project_registered_before_the_module_is_kept():
    ran: list[str] = []
    workflow = Workflow()
    workflow.modifier = Modifier(main=True)
    workflow.onstart(lambda log: ran.append("theirs start"))
    workflow.modifier = Modifier(main=False)
    assert module_handlers.carry(workflow, {"onstart": lambda: ran.append("ours start"), "onsuccess": lambda: None})
    run(workflow)
    assert ran == ["theirs start", "ours start"]


def test_a_snakemake_without_the_slots_carries_nothing_and_says_what_to_add():
    workflow = Workflow()
    del workflow._onsuccess
    namespace = {"onstart": print, "onsuccess": print}
    assert not module_handlers.carry(workflow, namespace)
    assert namespace == {"onstart": print, "onsuccess": print} and workflow.onstart.__self__ is workflow
    lines = module_handlers.lines_to_add(module_handlers.module_name(workflow))
    assert (
        "\n\nonstart:\n    flatlandia_workflow.onstart()\n\n\nonsuccess:\n    flatlandia_workflow.onsuccess()\n"
        in lines
    )


def test_the_main_snakefile_is_no_module():
    workflow = Workflow()
    workflow.modifier = Modifier(main=True)
    assert not module_handlers.as_module(workflow)
    assert not module_handlers.as_module(object())


def test_snakemake_registers_handlers_as_the_stand_in_does():
    """The installed Snakemake still keeps the main Snakefile's handlers in the slots carry() uses."""
    import snakemake.api  # noqa: F401  (snakemake.workflow imports it first)
    from snakemake.workflow import Workflow as Snakemakes

    for name in module_handlers.HANDLERS:
        source = inspect.getsource(getattr(Snakemakes, name))
        assert "is_main_snakefile()" in source and f"self._{name} = func" in source, source
