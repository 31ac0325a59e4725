"""The fleet room: one RobotFleet's reconcile (``reconcile.py``) and its steps in order:
observe (``observe.py``), plan (``plan.py``), render (``render.py``: pure, over
``render.wiring`` and ``render.deployments``), apply (``apply.py``: the one apply engine for
every kind the fleet writes) and the one status writer (``status_step.py`` over
``status.py``)."""
