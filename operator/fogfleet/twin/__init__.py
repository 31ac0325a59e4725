"""The twin (``fogfleet twin``): simulated shared services behind fogfleet's pods.

On a cluster whose pods do not really run (kwok), the twin watches fogfleet's pods through the
API server, simulates the request load of a scenario on the replicas that run, per tier, with
the queueing model and dispatcher of :mod:`fogfleet.autoscaling`, and serves the contract
metrics on 127.0.0.1 for Prometheus to scrape. ``scenario``, ``model`` and ``pods`` are pure;
``exporter`` and ``app`` do the I/O. CLI hook: :func:`fogfleet.twin.app.run_twin`.
"""
