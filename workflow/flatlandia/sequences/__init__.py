"""Sequences and fixes: the benchmark's protocol beyond one frame (a phone's GPS fix, a few frames
of motion) and its evaluation (the rules ``beyond_*`` and the table ``beyond_one_frame``).

``protocol`` (the sequence rule, the simulated odometry and GPS, what the priors may hold),
``evaluation`` (the anchors' errors on a scene map and in the cities, and their summaries),
``sequence_table`` (results/tables/beyond_one_frame.*), ``sequence_figures`` (risk-coverage and
reliability). The solver's side is ``flatlandia.solver.sequence`` and the ``fix`` of
``flatlandia.solver.locate``; the city search's, ``flatlandia.city.search``.
"""

#: floors of the odometry noise a sequence solver is told (a perfect step would tie the frames
#: rigidly), in metres and degrees: of the simulated sequences (``protocol``) and of a user's
#: (``flatlandia.localize``), one home, light to import
MIN_SIGMA_M, MIN_SIGMA_DEG = 0.05, 0.1
