"""The benchmark's own room: its measures (:mod:`~flatlandia.benchmark.metrics`: thresholds, error rows,
summaries, the answers' figures) and the geometric solver's runs of it
(:mod:`~flatlandia.benchmark.solver_runs`), imported by the fine stage, the city search, the
sequences and ``flatlandia score``."""
