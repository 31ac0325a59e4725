"""The files fogfleet generates from its own code, in one place: the CRDs from the API models
(``crds``), the chart's Grafana dashboard and alert rules over the metrics contract
(``dashboard``), and the writer and drift check of all of them (``files``: ``make crds``,
``make crds-check``)."""
