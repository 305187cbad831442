"""Beyond one frame: a phone's GPS fix and a few frames of motion, on the benchmark.

``protocol`` (the sequence rule, the simulated odometry and GPS, what the priors may hold),
``evaluate`` (the anchors' errors on a scene map and in the cities, and their summaries),
``table`` (results/tables/beyond_one_frame.*). The solver's side is ``flatlandia.solver.sequence``
and the ``fix`` of ``flatlandia.solver.localize``; the city search's, ``flatlandia.city.search``.
"""
