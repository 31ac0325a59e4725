"""A module pod's own counters, read from inside the pod with ``kubectl exec``: the test runner
needs no route to pod IPs and no Prometheus, and a NetworkPolicy cannot stand in the way.
The workload image has Python on its PATH; the metrics server listens on all addresses."""

from __future__ import annotations

import re
from typing import Any, Protocol

__all__ = ["Metrics", "parse", "scrape"]

_LINE = re.compile(r"^(\w+)(?:\{([^}]*)\})?\s+([0-9.eE+-]+|[+-]Inf|NaN)$")
_LABEL = re.compile(r'(\w+)="([^"]*)"')


class _Kubectl(Protocol):
    def kubectl(self, *args: str, check: bool = ..., timeout: float = ...) -> Any: ...


class Metrics:
    """One scrape: series as (name, labels) -> value."""

    def __init__(self, series: list[tuple[str, dict[str, str], float]]) -> None:
        self.series = series

    def total(self, name: str, **labels: str) -> float:
        """The sum of the series of ``name`` whose labels include ``labels`` (0 when none)."""
        return sum(
            value
            for n, have, value in self.series
            if n == name and all(have.get(k) == v for k, v in labels.items())
        )

    def has(self, name: str) -> bool:
        return any(n == name for n, _, _ in self.series)


def parse(text: str) -> Metrics:
    series = []
    for line in text.splitlines():
        m = _LINE.match(line.strip())
        if m:
            series.append((m.group(1), dict(_LABEL.findall(m.group(2) or "")), float(m.group(3))))
    return Metrics(series)


def scrape(kube: _Kubectl, namespace: str, pod: str, container: str, port: int) -> Metrics:
    """The pod's /metrics; raises AssertionError (kubectl's output) when it does not answer."""
    code = (
        "import urllib.request as u;"
        f"print(u.urlopen('http://127.0.0.1:{port}/metrics', timeout=5).read().decode())"
    )
    proc = kube.kubectl(
        "exec", pod, "-n", namespace, "-c", container, "--", "python", "-c", code, timeout=60
    )
    return parse(proc.stdout)
