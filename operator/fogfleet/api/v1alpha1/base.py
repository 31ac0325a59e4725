"""Shared pieces of the v1alpha1 wire models: the base model and Kubernetes quantities.

Conventions (STYLE.md): camelCase on the wire, unknown fields rejected, ints or quantity strings
(never floats) in specs, ``...Seconds``/``...Millis`` units in names.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError
from pydantic.alias_generators import to_camel

from fogfleet.contract.quantity import parse_cpu, parse_memory, parse_quantity

__all__ = [
    "MBPS",
    "CpuQuantity",
    "FogModel",
    "MemoryQuantity",
    "NonNegInt",
    "Number",
    "PosInt",
    "Quantity",
    "format_cores",
    "format_millicores",
    "parse_cpu",
    "parse_mbps",
    "parse_memory",
    "parse_millis",
    "parse_quantity",
    "refuse_duplicates",
    "status_part",
]

log = logging.getLogger(__name__)
M = TypeVar("M", bound=BaseModel)


class FogModel(BaseModel):
    """Base of every wire model: camelCase aliases, extra fields forbidden, immutable.

    The docstring under each field is its documentation: it becomes the field's description in
    the generated CRD, which is what ``kubectl explain`` prints (a test keeps every field
    documented).
    """

    model_config = ConfigDict(
        alias_generator=to_camel,
        use_attribute_docstrings=True,
        populate_by_name=True,
        extra="forbid",
        frozen=True,
        use_enum_values=False,
    )

    def wire(self) -> dict[str, Any]:
        """The object as it appears in YAML: camelCase, without unset optional fields."""
        return self.model_dump(by_alias=True, exclude_none=True, mode="json")


def parse_millis(value: str | float) -> float:
    """A ``...Millis`` quantity in seconds (the unit every model of the core computes in)."""
    return parse_quantity(value) / 1e3


MBPS = 1e6  # bit/s in one Mbps


def parse_mbps(value: str | float) -> float:
    """A ``...Mbps`` quantity in bit/s."""
    return parse_quantity(value) * MBPS


def format_millicores(cores: float) -> str:
    """Cores as whole millicores, always with the suffix: "100m" (labels, status, keys)."""
    return f"{round(cores * 1000)}m"


def format_cores(cores: float) -> str:
    """Cores as a short quantity for people: whole cores as "3", else millicores ("2500m")."""
    millis = round(cores * 1000)
    return str(millis // 1000) if millis % 1000 == 0 else f"{millis}m"


def _check_quantity(value: Any) -> Any:
    parse_quantity(value)
    return value


Quantity = Annotated[
    str | int,
    BeforeValidator(_check_quantity),
    Field(json_schema_extra={"x-kubernetes-int-or-string": True}),
]
CpuQuantity = Quantity


def _check_number(value: Any) -> Any:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(
            f"must be a number such as 12 or 0.4, written without quotes, not {value!r}"
        )
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"must be a finite number, zero or more, not {value!r}")
    return value


Number = Annotated[float, BeforeValidator(_check_number), Field(json_schema_extra={"minimum": 0})]
"""A plain non-negative number (``type: number`` in the CRD, as the API server accepts it):
milliseconds, rates, weights, factors. Unlike a quantity it takes no suffix and no quotes."""
MemoryQuantity = Quantity
PosInt = Annotated[int, Field(ge=1)]
NonNegInt = Annotated[int, Field(ge=0)]


def refuse_duplicates(values: list[Any], field: str) -> None:
    """Raise naming the field and the duplicate(s) when a list that names things repeats one
    (the CRD says the same with ``x-kubernetes-list-type``)."""
    seen: set[Any] = set()
    dup: set[str] = set()
    for value in values:
        if value in seen:
            dup.add(str(value))
        seen.add(value)
    if dup:
        raise ValueError(f"{field}: {', '.join(sorted(dup))} listed more than once")


def status_part(obj: Mapping[str, Any], key: str, model: type[M]) -> M | None:
    """``status.<key>`` of an object the operator wrote, read back as ``model``: the one way
    every reader gets it; None when there is none or it is not in the shape we write (logged)."""
    raw = (obj.get("status") or {}).get(key)
    if not raw:
        return None
    try:
        return model.model_validate(raw)
    except ValidationError:
        log.warning("Ignored an unreadable status.%s: %s", key, raw)
        return None
