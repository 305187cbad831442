"""city stage: one reference map of many scenes, an index that says where a query can be, and
the solver on the few regions it proposes."""
