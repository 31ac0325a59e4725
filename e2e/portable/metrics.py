"""The e2e suite's one reader of Prometheus' text format, on ``prometheus_client.parser``.

A module pod's own counters are read from inside the pod with ``kubectl exec`` (:func:`scrape`:
the test runner needs no route to pod IPs and no Prometheus, and a NetworkPolicy cannot stand
in the way; the workload image has Python on its PATH and its metrics server listens on all
addresses); an endpoint the runner reaches is read with :func:`read`."""

from __future__ import annotations

import urllib.request
from typing import Any, Protocol

from prometheus_client.parser import text_string_to_metric_families

__all__ = ["Metrics", "parse", "read", "scrape"]


class _Kubectl(Protocol):
    def kubectl(self, *args: str, check: bool = ..., timeout: float = ...) -> Any: ...


class Metrics:
    """One scrape: every sample as (name, labels, value); histogram samples keep their
    ``_bucket``/``_count``/``_sum`` names and counters their ``_total``."""

    def __init__(self, series: list[tuple[str, dict[str, str], float]]) -> None:
        self.series = series

    def _matching(self, name: str, labels: dict[str, str]) -> list[tuple[dict[str, str], float]]:
        return [
            (have, value)
            for n, have, value in self.series
            if n == name and all(have.get(k) == v for k, v in labels.items())
        ]

    def total(self, name: str, **labels: str) -> float:
        """The sum of the series of ``name`` whose labels include ``labels`` (0 when none)."""
        return sum(value for _, value in self._matching(name, labels))

    def has(self, name: str) -> bool:
        return any(n == name for n, _, _ in self.series)

    def totals(self, prefix: str = "") -> dict[str, float]:
        """Per sample name starting with ``prefix``, its series summed over their labels
        (histogram buckets left out: their sum means nothing)."""
        out: dict[str, float] = {}
        for n, _, value in self.series:
            if n.startswith(prefix) and not n.endswith("_bucket"):
                out[n] = out.get(n, 0.0) + value
        return out

    def by(self, name: str, label: str, **labels: str) -> dict[str, float]:
        """The series of ``name`` whose labels include ``labels``, summed per value of
        ``label``."""
        out: dict[str, float] = {}
        for have, value in self._matching(name, labels):
            out[have[label]] = out.get(have[label], 0.0) + value
        return out

    def buckets(self, name: str, **labels: str) -> dict[float, float]:
        """Histogram ``name``'s cumulative buckets (le -> count, +Inf as ``inf``) over the
        series whose labels include ``labels``; from one scrape, so consistent together."""
        return {float(le): n for le, n in self.by(f"{name}_bucket", "le", **labels).items()}


def parse(text: str) -> Metrics:
    return Metrics(
        [
            (sample.name, dict(sample.labels), float(sample.value))
            for family in text_string_to_metric_families(text)
            for sample in family.samples
        ]
    )


def read(url: str, timeout: float = 5) -> Metrics:
    """One scrape of an endpoint the test runner reaches."""
    with urllib.request.urlopen(url, timeout=timeout) as response:
        return parse(response.read().decode())


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
