"""The plan in words, from the planner's own answers: why each instance runs where it runs
and not on each other node it could use (``alternatives``: ``fogfleet explain``, ``kubectl
fogfleet why``), and why a fleet cannot be placed or runs degraded (``shortfall``: the
operator's conditions and Events, the CLI's refusals)."""
