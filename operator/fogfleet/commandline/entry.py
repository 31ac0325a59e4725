"""The ``fogfleet`` command's entry point: size the numeric libraries' thread pools before
NumPy loads them, then run the CLI (``fogfleet.commandline.cli.main``).

NumPy's OpenBLAS starts a thread per core, and its idle threads spin a while before they
sleep. The planner's matrix products are small (moves x nodes), so a second thread buys
nothing measurable: the warehouse decision time is 0.42 s with it and 0.43 s without, a
300-robot first plan 23.4 vs 23.8 s. But it spins on the core the API server and
kube-controller-manager need: an incremental re-plan at 1000 robots used 0.70-0.84 s of CPU
for 0.41-0.49 s of wall with it, and as much CPU as wall (0.46-0.51 s) without. In a pod
with a CPU limit, the spinning also spends the quota. A value the user set is kept.
"""

from __future__ import annotations

import os

__all__ = ["THREAD_POOL_VARIABLES", "kubectl_plugin", "main", "pin_thread_pools"]

# read by OpenBLAS (NumPy's wheels), OpenMP and MKL when they load
THREAD_POOL_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def pin_thread_pools() -> None:
    """One thread per numeric library unless the environment says otherwise; effective only
    before NumPy is first imported."""
    for name in THREAD_POOL_VARIABLES:
        os.environ.setdefault(name, "1")


def main() -> int:
    pin_thread_pools()
    from fogfleet.commandline.cli import main as cli_main

    return cli_main()


def kubectl_plugin() -> int:
    """The ``kubectl-fogfleet`` command (``fogfleet.commandline.kubectl``), with the same
    thread pools."""
    pin_thread_pools()
    from fogfleet.commandline.kubectl.cli import main as plugin_main

    return plugin_main()
