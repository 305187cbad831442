"""Which torch device the learned models run on: the config's ``device`` (``auto`` | ``cpu`` | ``cuda``).

Why one place: the coarse and fine trainings and evaluations and the learned image backends all
read the same setting, and a ``cuda`` that cannot be honoured must stop the run with one line
naming the setting before any job, not a CUDA traceback hours into a training. ``auto`` is CUDA
when torch sees a GPU, else the CPU; ``cpu`` and ``auto`` without a GPU take exactly the code path
and the numbers of a run before this setting existed (models are built and seeded on the CPU and
then moved, the CPU path moves nothing).

torch is imported only when a device is resolved: the workflow's parse checks ``cuda`` with
:func:`cuda_problem` and never imports torch for ``auto`` or ``cpu``.
"""

from __future__ import annotations

import os

from flatlandia.plumbing.errors import InputError

#: the values of the config's ``device``
CHOICES = ("auto", "cpu", "cuda")
#: what an error names: the setting, as every config error does
SETTING = "config: 'device'"


def _check_choice(setting: str) -> str:
    if setting not in CHOICES:
        raise InputError(SETTING, f"{setting!r} is not one of {', '.join(CHOICES)}")
    return setting


def cuda_problem() -> str | None:
    """Why CUDA cannot be used here (None when it can): torch built without CUDA, or no GPU visible."""
    import torch

    if torch.version.cuda is None:
        return f"this torch ({torch.__version__}) is built without CUDA"
    if not torch.cuda.is_available():
        visible = os.environ.get("CUDA_VISIBLE_DEVICES")
        where = f" (CUDA_VISIBLE_DEVICES={visible!r})" if visible is not None else ""
        return f"torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU on this machine{where}"
    return None


def _cuda_refused(problem: str) -> str:
    return (
        f"cuda asked for, but {problem}; use device: auto (CUDA when there is a GPU, else the CPU) "
        "or cpu, or run on a machine with a GPU and a CUDA build of torch"
    )


def cuda_error(problem: str) -> str:
    """The one line a ``cuda`` that cannot be honoured stops with (after ``ERROR: ``)."""
    return f"{SETTING}: {_cuda_refused(problem)}"


def resolve(setting: str = "auto"):
    """The ``torch.device`` of a setting: ``cpu``; ``cuda`` (raises :class:`InputError` naming the
    setting when CUDA is unusable); ``auto``: CUDA when torch sees a GPU, else the CPU.

    On CUDA, cuBLAS is asked for its deterministic workspace (``CUBLAS_WORKSPACE_CONFIG``, before
    CUDA starts) so that :func:`flatlandia.checkpoints.set_determinism` holds for the matrix
    products; the scatter kernels stay non-deterministic on a GPU (CUDA runs repeat up to rounding)."""
    import torch

    setting = _check_choice(setting)
    if setting == "cpu":
        return torch.device("cpu")
    problem = cuda_problem()
    if problem is not None:
        if setting == "cuda":
            raise InputError(SETTING, _cuda_refused(problem))
        return torch.device("cpu")
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    return torch.device("cuda")


def torch_device(value):
    """A ``torch.device`` from the config's setting (:func:`resolve`) or a device as is: what the
    entry functions take, so that callers holding a resolved device do not resolve it again."""
    import torch

    return resolve(value) if isinstance(value, str) and value in CHOICES else torch.device(value)


def workflow_check(setting: str, jobs_run_here: bool = True) -> str | None:
    """The ERROR line (without ``ERROR: ``) for the workflow's parse, or None: a ``cuda`` where the
    jobs run and CUDA is unusable. A cluster run's submitting host (``jobs_run_here`` False) needs
    no GPU: each job checks again on its node, where its Snakemake parses the workflow."""
    if setting not in CHOICES:
        return f"{SETTING}: {setting!r} is not one of {', '.join(CHOICES)}"
    if setting != "cuda" or not jobs_run_here:
        return None
    problem = cuda_problem()
    return cuda_error(problem) if problem else None


def dry_run_warning(problem: str) -> str:
    """The WARNING line (without ``WARNING: ``) a dry run prints instead of stopping on the problem
    :func:`workflow_check` found: a plan for a GPU machine can be previewed on any machine."""
    return f"{problem}; this dry run plans the jobs anyway, a run here stops with it as an ERROR"


def model_device(model):
    """The device a model's weights are on (the CPU for a model without any)."""
    import torch

    return next((p.device for p in model.parameters()), torch.device("cpu"))


def describe(device) -> str:
    """The device in words for logs and notes: ``cpu`` or ``cuda (NVIDIA H100 80GB HBM3)``."""
    import torch

    device = torch.device(device)
    if device.type != "cuda":
        return device.type
    return f"cuda ({torch.cuda.get_device_name(device)})"
