"""Beyond one frame: a phone's GPS fix and a few frames of motion, on the benchmark.

``protocol`` (the sequence rule, the simulated odometry and GPS, what the priors may hold),
``evaluate`` (the anchors' errors on a scene map and in the cities, and their summaries),
``table`` (results/tables/beyond_one_frame.*). The solver's side is ``flatlandia.solver.sequence``
and the ``fix`` of ``flatlandia.solver.localize``; the city search's, ``flatlandia.city.search``.
"""

#: floors of the odometry noise a sequence solver is told (a perfect step would tie the frames
#: rigidly), in metres and degrees: of the simulated sequences (``protocol``) and of a user's
#: (``flatlandia.localize``), one home, light to import
MIN_SIGMA_M, MIN_SIGMA_DEG = 0.05, 0.1
