"""``kubectl fogfleet`` (the ``kubectl-fogfleet`` command, a kubectl plugin): why a module runs
where it runs, the fleet's measured vs predicted figures, what a re-plan would change, and
what-if plans, read from a running cluster and planned with the operator's own code, never
applied."""

from __future__ import annotations

__all__ = ["main"]


def main() -> int:
    """The ``kubectl-fogfleet`` console script: one thread per numeric library (as the
    ``fogfleet`` command, ``fogfleet.entry``), then ``plugin.cli.main``."""
    from fogfleet.entry import pin_thread_pools

    pin_thread_pools()
    from fogfleet.plugin.cli import main as cli_main

    return cli_main()
