"""The measuring room: what the cluster and Prometheus show of the fleets as they run. Links
(``links.py``), drift of measured against predicted misses (``observed.py``,
``drift_report.py``), profiling Jobs (``profiling.py``), the usage status of the shared kinds
(``usage.py``). Each writes into the fleets' state (``controllers/state.py``); none imports
another's module or the fleet room. Whether these loops run at all (``Monitoring``) is the
shared ``controllers/monitoring.py``: the dependencies hold it and every fleet's status
reads it."""
