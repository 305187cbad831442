"""The shared plumbing of every stage: atomic writers (``files``), names that become paths
(``names``), text escaping (``escape``), PLY headers (``ply``), the input error (``errors``), the
checks at the doors (``validate``), logging for rule scripts (``rule_log``), Snakemake's stale locks
(``stale_locks``), the rerun notice (``rerun_notice``), the audit trail (``provenance``), the run
summary (``summary``), a rule outside Snakemake (``debug``), the scheduler's choice (``scheduler``)
and torch_geometric's light import (``pyg``). Nothing here imports a stage."""
