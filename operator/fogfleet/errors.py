"""The one error tree of fogfleet.

    FogfleetError
    ├── InvalidSpec            bad input: names the object, the field and the reason (CLI exit 2,
    │   │                      kopf PermanentError, Ready=False with reason InvalidSpec)
    │   ├── DanglingReference  a reference names an object that does not exist
    │   └── Infeasible         valid objects, but no placement can satisfy them
    └── DependencyUnavailable  a cluster or Prometheus call failed; retry (kopf TemporaryError)

Adapters translate library exceptions into this tree with ``raise ... from exc``; the two
commands turn it into exit codes in one place, ``fogfleet.commandline.exits``.
"""

from __future__ import annotations

__all__ = [
    "DanglingReference",
    "DependencyUnavailable",
    "FogfleetError",
    "Infeasible",
    "InvalidSpec",
]


class FogfleetError(Exception):
    """Base of every error fogfleet raises on purpose."""

    reason = "Error"


class InvalidSpec(FogfleetError):
    """An object is invalid. ``obj`` is ``Kind/name`` and ``field`` a dotted path."""

    reason = "InvalidSpec"

    def __init__(self, obj: str, field: str, message: str) -> None:
        self.obj = obj
        self.field = field
        self.message = message
        where = f"{obj}: {field}" if field else obj
        super().__init__(f"{where}: {message}")


class DanglingReference(InvalidSpec):
    reason = "DanglingReference"


class Infeasible(InvalidSpec):
    reason = "Infeasible"


class DependencyUnavailable(FogfleetError):
    reason = "DependencyUnavailable"
