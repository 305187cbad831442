"""The solver's settings: the config section ``solver`` as one value (:class:`SolverConfig`).

A module of its own so that every solver module (the pipeline, the priors, the learned priors)
reads the same class without importing the pipeline.
"""

from __future__ import annotations

from flatlandia import config


@config.settings("solver")
class SolverConfig:
    """The solver's settings, one field per key of the config section ``solver`` (types and defaults
    from workflow/schemas/config.schema.yaml; each is described in config/README.md, ``solver.*``)."""
