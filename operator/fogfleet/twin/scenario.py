"""The twin's load scenario: which shared services the robots call, how often, over time.

YAML (``fogfleet twin --scenario FILE``)::

    services:
    - module: object-detector      # SoftwareModule name
      namespace: shared-detector   # default: --namespace, else "default"
      robots: 30                   # informational; requests are per service
      privateShare: 0.3            # fraction of requests from privacy-constrained robots
      phases:                      # piecewise-constant arrival rate from atSeconds on
      - {atSeconds: 0, requestsPerSecond: 20}
      - {atSeconds: 60, requestsPerSecond: 90}

Times count from the moment the twin (re)loads the file. Pure: no I/O except
:func:`load_scenario`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from fogfleet.errors import InvalidSpec

__all__ = ["Phase", "Scenario", "Service", "load_scenario", "parse_scenario"]


@dataclass(frozen=True)
class Phase:
    at_seconds: float
    requests_per_second: float


@dataclass(frozen=True)
class Service:
    module: str
    namespace: str
    phases: tuple[Phase, ...]
    private_share: float = 0.0
    robots: int = 1

    @property
    def key(self) -> tuple[str, str]:
        return self.namespace, self.module

    def rate_at(self, t: float) -> float:
        """Arrival rate (requests/s) at ``t`` seconds after the scenario started."""
        rate = 0.0
        for phase in self.phases:
            if phase.at_seconds <= t:
                rate = phase.requests_per_second
        return rate


@dataclass(frozen=True)
class Scenario:
    services: tuple[Service, ...]

    def service(self, namespace: str, module: str) -> Service | None:
        for s in self.services:
            if s.key == (namespace, module):
                return s
        return None


def _number(where: str, field: str, value: Any, *, low: float, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidSpec(where, field, f"must be a number, not {value!r}")
    if value < low or (high is not None and value > high):
        bound = f"between {low:g} and {high:g}" if high is not None else f"at least {low:g}"
        raise InvalidSpec(where, field, f"must be {bound}, not {value!r}")
    return float(value)


def parse_scenario(
    data: Any, *, where: str = "scenario", default_namespace: str = "default"
) -> Scenario:
    """Validate a scenario document; errors name the file and the field."""
    if not isinstance(data, Mapping) or not isinstance(data.get("services"), list):
        raise InvalidSpec(where, "services", "must be a list of services")
    services = []
    for i, raw in enumerate(data["services"]):
        at = f"services[{i}]"
        if not isinstance(raw, Mapping) or not isinstance(raw.get("module"), str):
            raise InvalidSpec(where, f"{at}.module", "each service needs a module name")
        unknown = set(raw) - {"module", "namespace", "robots", "privateShare", "phases"}
        if unknown:
            raise InvalidSpec(where, f"{at}.{sorted(unknown)[0]}", "unknown field")
        phases_raw = raw.get("phases")
        if not isinstance(phases_raw, list) or not phases_raw:
            raise InvalidSpec(where, f"{at}.phases", "must be a non-empty list")
        phases = []
        for k, p in enumerate(phases_raw):
            pat = f"{at}.phases[{k}]"
            if not isinstance(p, Mapping):
                raise InvalidSpec(where, pat, "must be {atSeconds, requestsPerSecond}")
            phases.append(
                Phase(
                    _number(where, f"{pat}.atSeconds", p.get("atSeconds", 0), low=0),
                    _number(where, f"{pat}.requestsPerSecond", p.get("requestsPerSecond"), low=0),
                )
            )
        services.append(
            Service(
                raw["module"],
                str(raw.get("namespace") or default_namespace),
                tuple(sorted(phases, key=lambda p: p.at_seconds)),
                _number(where, f"{at}.privateShare", raw.get("privateShare", 0), low=0, high=1),
                int(_number(where, f"{at}.robots", raw.get("robots", 1), low=1)),
            )
        )
    keys = [s.key for s in services]
    if len(set(keys)) != len(keys):
        raise InvalidSpec(where, "services", "a (namespace, module) appears twice")
    return Scenario(tuple(services))


def load_scenario(path: str | Path, default_namespace: str = "default") -> Scenario:
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InvalidSpec(str(p), "", f"cannot read the scenario: {exc}") from exc
    return parse_scenario(data, where=str(p), default_namespace=default_namespace)
