"""Looking at queries: a figure per test query, a gallery of a scene's worst ones, and a
self-contained HTML map viewer per scene, all drawn from one model of the scene (``scene``).

Why: where a method fails, and why, is read from maps (the local map laid on the reference map
at the true pose and at each estimate), not from Parquet rows.
"""
