"""Pure scaling core: metrics contract, HPA behaviour, queueing model, dispatch, policies.

``contract`` names the metrics; ``behavior`` is the HPA's stabilisation and rate limits;
``queueing`` the M/M/k, M/M/k/K and M/M/k/setup models of tinyKube section III-B; ``dispatch``
admission and routing; ``policy`` turns a MetricsSnapshot into a ScaleDecision; ``bench`` is
the seeded tinyKube benchmark. Nothing here does I/O or imports kopf, kubernetes or Prometheus
clients (import-linter contract ``pure-core``).
"""
