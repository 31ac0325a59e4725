"""Cross-field rules, stated once: a CEL expression the API server checks on ``kubectl apply``
and the same rule as a predicate the models check (for the CLI, the operator and tests), with
one message naming the field and the reason.

A model lists its rules in ``RULES`` and calls :func:`enforce` from a ``model_validator``;
``artefacts.crds`` writes ``rule.crd()`` into the schema node of that model. A test checks that
every model rule reaches its CRD.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["CrossFieldRule", "enforce"]


@dataclass(frozen=True)
class CrossFieldRule:
    cel: str
    """The rule in CEL, on the object it belongs to (``self``)."""
    message: str
    """``field: reason``, as both the API server and the models report it."""
    holds: Callable[[Any], bool]
    """The same rule on the model instance."""

    def crd(self) -> dict[str, str]:
        """The ``x-kubernetes-validations`` entry."""
        return {"rule": self.cel, "message": self.message}


def enforce(model: Any, rules: Iterable[CrossFieldRule]) -> None:
    """Raise ``ValueError(rule.message)`` for the first rule ``model`` breaks."""
    for rule in rules:
        if not rule.holds(model):
            raise ValueError(rule.message)
