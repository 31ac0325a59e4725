"""Benchmarks of the pure core, outside it: ``fogfleet bench scheduling|autoscaling|replan``.

``scheduling`` (the warehouse and synthetic fleets, optimality gap, decision time, the paper's
stand-in), ``replan`` (whole-fleet vs incremental re-plan), ``autoscaling`` (the seeded tinyKube
discrete-event benchmark) and ``suite`` (the scheduling benchmarks in one table). The core
(``api``, ``domain``, ``scheduling``, ``sim``, ``autoscaling``, ``render``) never imports this
package (import-linter contract ``core-without-extras``); tests use ``scheduling``'s fleets.
"""
