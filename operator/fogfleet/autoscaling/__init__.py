"""Pure scaling core: HPA behaviour, queueing model, dispatch, policies.

``behavior`` is the HPA's stabilisation and rate limits; ``queueing`` the M/M/k, M/M/k/K and
M/M/k/setup models of tinyKube section III-B; ``dispatch`` admission and routing; ``policy``
turns a MetricsSnapshot into a ScaleDecision. The metrics are named in
``fogfleet.contract.metrics``; the seeded tinyKube benchmark is ``fogfleet.bench.autoscaling``.
Nothing here does I/O or imports kopf, kubernetes or Prometheus clients (import-linter contract
``pure-core``).
"""
