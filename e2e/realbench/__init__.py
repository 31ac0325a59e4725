"""The paper's real-world comparison on the bed's real nodes (issue 12), and how far the
simulator is from it.

``python -m e2e.realbench`` (``make bench-real``) runs ``manifests/examples/warehouse-lite`` with
each of ``nsga2``, ``k8s-default`` and ``onboard`` on the running bed, measures missed cycles
from the workload's own counters in Prometheus over a fixed window, simulates the same
placements with ``fogfleet.sim`` and prints both side by side.

* ``measure``: counter snapshots from Prometheus and miss rates over a window;
* ``scenario``: the fleet's objects, moved into a run's namespace, and its offline Problem;
* ``run``: one run on the cluster (apply, wait, warm up, measure, delete) and the CLI.
"""
