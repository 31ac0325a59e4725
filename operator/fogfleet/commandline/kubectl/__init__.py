"""``kubectl fogfleet`` (the ``kubectl-fogfleet`` command, a kubectl plugin): why a module runs
where it runs, the fleet's measured vs predicted figures, what a re-plan would change, and
what-if plans, read from a running cluster and planned with the operator's own code, never
applied."""
