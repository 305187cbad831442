"""Score your own poses: an external method's poses of the benchmark's queries, scored exactly as
the built-in methods are (``flatlandia score``, rule ``external_eval``).

A poses file (CSV or Parquet) has one row per query: ``scene``, ``token`` and one pose form,
either ``x_m, y_m, theta_deg`` (the scene's metric frame: x east, y north, metres; the viewing
axis counter-clockwise from east, degrees) or ``lon, lat, heading_deg`` (WGS84 degrees and a
compass heading, clockwise from north: heading = 90 - theta). Optional columns: ``map_type``
(``gt`` or ``depth``, default ``depth``), ``proposal`` (``gtbb``, ``whole``, ``coarse-sim``,
``coarse-trip``, ``coarse-simtrip``, ``coarse-solver``; default ``whole``) name the setting a row
was computed in (one run per setting; an empty cell takes the default), ``seconds`` its query time
(empty: unknown), ``status`` (``ok``, ``ambiguous``, ``no pose``: the answered are the ``ok``) and
``probability`` (of being within (5 m, 5 deg)) the answer as ``flatlandia localize --batch``
writes it (without them every pose is answered, as before). Other columns are ignored. A query
without a pose is a row left out, or one whose three pose cells are empty (CSV) or null (Parquet),
as ``poses_template.csv`` of the export comes.

Why the same functions: a row of an external run must read against the solver's and the learned
models' rows, so it is built by :func:`flatlandia.benchmark.metrics.error_row` (errors by
:func:`flatlandia.geo.pose_errors`) and summarised by :func:`flatlandia.benchmark.metrics.summarise`;
a query without a pose is a failure exactly as the solver's (no pose: infinite error, 180 deg).
Every problem of a file is one :class:`flatlandia.plumbing.errors.InputError` naming the file; what looks
like a convention mix-up (lon/lat swapped, radians for degrees) is a warning, not an error.
"""

from flatlandia.score.external_runs import (
    Run,
    Scores,
    builtin_setting,
    check_name,
    default_strategy,
    errors_table,
    external_entries,
    external_run,
    run_summary,
    score_file,
    score_run,
)
from flatlandia.score.plausibility import plausibility, row_plausibility, scene_extents
from flatlandia.score.poses import (
    DEFAULT_MAP_TYPE,
    DEFAULT_PROPOSAL,
    FORMS,
    GEOGRAPHIC,
    KEYS,
    METRIC,
    Poses,
    read_poses,
    to_metric,
)
from flatlandia.score.render import SCORE_COLUMNS, scores_markdown, write_scores
from flatlandia.score.scenes import BENCHMARK_RECORD, BenchmarkScene, read_scene, results_scenes

__all__ = [
    "BENCHMARK_RECORD",
    "DEFAULT_MAP_TYPE",
    "DEFAULT_PROPOSAL",
    "FORMS",
    "GEOGRAPHIC",
    "KEYS",
    "METRIC",
    "SCORE_COLUMNS",
    "BenchmarkScene",
    "Poses",
    "Run",
    "Scores",
    "builtin_setting",
    "check_name",
    "default_strategy",
    "errors_table",
    "external_entries",
    "external_run",
    "plausibility",
    "read_poses",
    "read_scene",
    "results_scenes",
    "row_plausibility",
    "run_summary",
    "scene_extents",
    "score_file",
    "score_run",
    "scores_markdown",
    "to_metric",
    "write_scores",
]
