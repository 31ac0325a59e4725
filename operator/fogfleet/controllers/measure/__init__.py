"""The measuring room: what the cluster and Prometheus show of the fleets as they run. Links
(``links.py``), drift of measured against predicted misses (``observed.py``,
``drift_report.py``), profiling Jobs (``profiling.py``), the usage status of the shared kinds
(``usage.py``) and whether these loops run at all (``monitoring.py``). Each writes into the
fleets' state (``controllers/state.py``); none imports another's module or the fleet room."""
