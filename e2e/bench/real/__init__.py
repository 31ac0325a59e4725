"""The paper's real-world experiment (multi-robot-edge-cloud-scheduling IV-C, issue 33) on the
``paper`` bed's real nodes, and how far the simulator is from it.

``python -m e2e.bench.real`` (``make bench-real``) starts the paper bed when none runs, then runs
the fleet of ``e2e/bench/real/paper`` once per scheduled run (nsga2, kube-scheduler, on-board,
nsga2 without the closed loop), measures missed cycles from the workload's own counters in
Prometheus over a fixed window, simulates the placement each run really had with
``fogfleet.sim`` and writes every run to ``bench-real.json``.

* ``protocol``: the arms, the schedule (blocks, alternating order), timing and endpoint;
* ``scenario``: the fleet's objects, moved into a run's namespace, and its offline Problem;
* ``measure``: counter snapshots from Prometheus and miss rates over a window;
* ``run``: one run on the cluster (apply, wait, warm up, measure, delete) and the CLI;
* ``stats``: the bootstrap CI of the reduction and the exact Mann-Whitney test;
* ``report``, ``plot``: the summary, tables, docs page and figure from bench-real.json;
* ``modelcheck``: what the planner, the kube-scheduler emulation and the simulator predict
  for the bed before it runs.
"""
