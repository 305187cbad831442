"""The benchmark's vocabulary: the names of its methods, local-map types, proposals and strategies,
with their labels, in one place.

A *slug* is how the code names a thing: a rule wildcard, a part of a path (``flatlandia.paths``),
a config value, a table column's value; a *label* is how a table or a figure writes it. The rules,
``score``, ``localize``, ``batch``, ``export``, the tables, the figures, the tests and the
benchmarks take their names from here, so a new proposal type is one :class:`Proposal` in
:data:`PROPOSALS` (and the schema's enums of proposals, which tests/test_vocabulary.py checks
against this list; docs/architecture.md, "Adding a proposal type").

No imports beyond the standard library: the rules read this module while Snakemake parses them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

# ----------------------------------------------------------------------------- local maps

#: the local-map types a query comes with: the published (ground-truth) local map, or the one
#: made from the image's depth map
MAP_TYPES = ("gt", "depth")
MAP_TYPE_LABELS = {"gt": "GT local map", "depth": "depth local map"}

# ----------------------------------------------------------------------------- methods

#: the geometric solver's methods: with the training split's cameras, and without them (the camera
#: prior off for that run: what the whole-map figures owe to the cameras)
SOLVER_METHODS = ("solver", "solver-noprior")
#: the paper's learned baselines: slug -> model name (the architecture fine.models builds, and the
#: paper's name of it)
LEARNED_METHODS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
#: every built-in method of the fine stage, in the order of the legends; an external method
#: (config ``external``, ``flatlandia score``) is any other name
METHODS = (*SOLVER_METHODS, *LEARNED_METHODS)
#: the methods' names in the tables (the fine table's ``method_label``)
METHOD_LABELS = {
    "solver": "geometric solver",
    "solver-noprior": "geometric solver, no camera prior",
    **LEARNED_METHODS,
}
#: the methods' names in the figures, as the paper writes them (its tables' keys)
METHOD_SHORT_LABELS = {"solver": "solver", "solver-noprior": "solver, no camera prior", **LEARNED_METHODS}
#: an ablation's method -> the method it ablates (the `ablations` target's table puts each ablation
#: run beside that method's run on the same map type and proposal)
ABLATES = {"solver-noprior": "solver"}
#: the city rows' methods (rule city_eval): today's solver on the whole city, the city search
CITY_METHODS = ("solver", "index")


def is_builtin(method: str) -> bool:
    """One of the benchmark's own fine methods (else an external one, scored from its poses)."""
    return method in METHODS


# ----------------------------------------------------------------------------- answers

#: an answer's status (flatlandia.localize.answer_status): ``ok`` (answered: its calibrated
#: probability of being within (5 m, 5 deg) is at least solver.answer_probability), ``ambiguous``
#: (below it), or ``no pose``; the batch's poses file carries it, and ``flatlandia score`` counts
#: the answered from it
ANSWERED, AMBIGUOUS, NO_POSE = "ok", "ambiguous", "no pose"
STATUSES = (ANSWERED, AMBIGUOUS, NO_POSE)

# ----------------------------------------------------------------------------- strategies

#: how a coarse model's scores become a proposal (coarse.evaluation): the N_LM best objects, 2 N_LM,
#: every object within 30 m of the best one
COARSE_STRATEGIES = ("N_LM", "2N_LM", "R_30")
#: the oracle box: the objects around the query's true matches and camera
ORACLE_STRATEGY = "GT-BB"
#: the solver's training-free box (coarse.solver_proposals): the GT-BB box around its own matches
BOX_STRATEGY = "BB"
#: every strategy a proposal table holds, in the order of the export's proposals.csv
STRATEGIES = (ORACLE_STRATEGY, *COARSE_STRATEGIES, BOX_STRATEGY)
#: the coarse stage's losses (config coarse.losses), each one trained model, and their labels
COARSE_LOSSES = {"sim": "Sim", "trip": "Trip", "simtrip": "Sim+Trip"}

# ----------------------------------------------------------------------------- proposals


@dataclass(frozen=True)
class Proposal:
    """A proposal type: the map region a fine run searches for each query.

    ``slug``: the run's third part (``{method}_{map_type}_{proposal}``) and the config's value.
    ``label``: the tables' strategy label of a region of the map itself (``GT-BB``, ``whole map``),
    or the coarse source's label that comes before its strategy (``Sim+Trip 2N_LM``).
    ``figure_label``: the figures' panel title. ``coarse``: the coarse source whose proposal table
    (``paths.coarse_proposals(coarse)``) holds the regions; '' for a region computed from the map
    (``flatlandia.proposals.for_queries``). ``strategy_key``: the config key choosing which of that
    table's strategies the fine runs use. ``priors``: the region of the learned priors a depth-map
    solver run reads (rule solver_priors): a verifier learned on the same region, else the scale
    prior alone.
    """

    slug: str
    label: str
    figure_label: str
    coarse: str = ""
    strategy_key: str = ""
    priors: str = "scale"


#: every proposal type, in the figures' panel order (the oracle box, the coarse sources, the whole map)
PROPOSALS: dict[str, Proposal] = {
    p.slug: p
    for p in (
        Proposal("gtbb", ORACLE_STRATEGY, "GT-BB proposals", priors="gtbb"),
        Proposal("coarse-sim", "Sim", "coarse proposals (Sim)", "sim", "fine.coarse_strategy"),
        Proposal("coarse-trip", "Trip", "coarse proposals (Trip)", "trip", "fine.coarse_strategy"),
        Proposal("coarse-simtrip", "Sim+Trip", "coarse proposals (Sim+Trip)", "simtrip", "fine.coarse_strategy"),
        Proposal("coarse-solver", "Solver", "coarse proposals (solver)", "solver", "coarse.solver.fine_strategy"),
        Proposal("whole", "whole map", "whole reference map", priors="whole"),
    )
}
#: the whole reference map: the fine stage without a coarse one (the default of score and localize)
WHOLE = "whole"
#: the oracle box
GTBB = "gtbb"
#: the proposals read from a coarse stage's table: slug -> its source's label
COARSE_PROPOSALS = {s: p.label for s, p in PROPOSALS.items() if p.coarse}
#: the proposals computed from the map itself (no coarse stage): what a new scene is evaluated on
MAP_PROPOSALS = tuple(s for s, p in PROPOSALS.items() if not p.coarse)
#: the regions rule solver_priors fits the learned priors for (``scale``: the scale prior alone)
PRIOR_REGIONS = ("whole", "gtbb", "scale")


def proposal(slug: str) -> Proposal:
    """The proposal type ``slug`` (KeyError naming the known ones otherwise)."""
    try:
        return PROPOSALS[slug]
    except KeyError:
        raise KeyError(f"unknown proposal {slug!r}: one of {', '.join(PROPOSALS)}") from None


def coarse_source(slug: str) -> str:
    """The coarse source (``sim``, ``solver``...) of a coarse proposal; '' for a map region."""
    return proposal(slug).coarse


def coarse_proposal(source: str) -> str:
    """The proposal slug of a coarse source (``sim`` -> ``coarse-sim``)."""
    return next(s for s, p in PROPOSALS.items() if p.coarse == source)


def prior_region(slug: str) -> str:
    """The learned priors' region a depth-map solver run on proposal ``slug`` reads."""
    return proposal(slug).priors


def strategy_key(slug: str) -> str:
    """The config key that picks the strategy of a coarse proposal's table ('' for a map region)."""
    return proposal(slug).strategy_key


def config_value(config: Mapping, key: str):
    """The value of a dotted config key (``coarse.solver.fine_strategy``) in a resolved config."""
    value = config
    for part in key.split("."):
        value = value[part]
    return value


def coarse_strategy(slug: str, config: Mapping) -> str | None:
    """The strategy of a coarse proposal's table that the fine runs use, by ``config`` (a resolved
    config: fine.coarse_strategy, or coarse.solver.fine_strategy for the solver's proposals); None
    for a map region, which has no strategy to pick."""
    key = strategy_key(slug)
    return str(config_value(config, key)) if key else None


def strategy_label(slug: str, strategy: str | None = None) -> str:
    """The tables' strategy label of a run on proposal ``slug`` (its coarse table's ``strategy``):
    ``GT-BB``, ``whole map``, or the coarse source's label and the strategy (``Sim+Trip 2N_LM``)."""
    p = PROPOSALS.get(slug)
    if p is None:
        return f"{slug} {strategy}"
    return f"{p.label} {strategy}" if p.coarse else p.label


# ----------------------------------------------------------------------------- fine runs


def run_name(method: str, map_type: str, proposal: str) -> str:
    """A fine run's name ``{method}_{map_type}_{proposal}`` (a path part: results/fine/{run}/)."""
    return f"{method}_{map_type}_{proposal}"


def split_run(run: str) -> tuple[str, str, str]:
    """(method, map_type, proposal) of a run name (a method's slug may hold '_', the others not)."""
    method, map_type, proposal = run.rsplit("_", 2)
    return method, map_type, proposal


def ablated_run(run: str) -> str | None:
    """The run an ablation run ablates (``solver-noprior_depth_whole`` -> ``solver_depth_whole``);
    None for a run that ablates nothing."""
    method, map_type, proposal = split_run(run)
    return run_name(ABLATES[method], map_type, proposal) if method in ABLATES else None


#: how a learned model was trained (rule fine_train's ``train`` wildcard): on the oracle box (the
#: paper's), or on simulated coarse proposals
TRAIN_REGIMES = ("gtbb", "coarse")


def train_regime(slug: str, strategy: str | None, coarse_training: bool) -> str:
    """The training proposals of the learned model a run on proposal ``slug`` evaluates: ``coarse``
    (simulated coarse proposals) for a coarse proposal when fine.coarse_training.enabled, else
    ``gtbb``; the solver's boxes (strategy BB) are what the GT-BB-trained model knows."""
    coarse = bool(proposal(slug).coarse)
    return "coarse" if coarse and coarse_training and strategy != BOX_STRATEGY else "gtbb"
