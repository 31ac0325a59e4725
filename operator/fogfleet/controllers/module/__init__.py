"""The module room: a shared SoftwareModule scaled from its SLO metrics (``scaling.py``, over
what it reads from Prometheus in ``metrics.py``)."""
