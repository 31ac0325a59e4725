"""fogfleet's command line: one package, two commands.

* ``fogfleet`` (``cli``): validate, plan, explain, simulate and render fleets from CR YAML,
  generate the CRDs, run the operator, run the benchmarks;
* ``kubectl fogfleet`` (``kubectl``, a kubectl plugin): why a module runs where it runs, the
  fleet's measured vs predicted figures, what a re-plan would change, what-if plans, read
  from a running cluster;
* ``entry``: both console scripts' entry points (the numeric libraries' thread pools sized
  before NumPy loads);
* ``exits``: how an error ends either command, decided in one place.

Both plan through ``fogfleet.snapshot``; the plugin imports nothing from the operator's
controllers or runtime (``.importlinter``).
"""
