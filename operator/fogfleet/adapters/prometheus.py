"""Prometheus, as the scaler reads it: instant PromQL queries through prometheus-api-client.

Every call blocks (``requests`` underneath); the controller runs it in a worker thread, never
on the event loop. Library errors are translated into the fogfleet error tree in one place,
:func:`map_errors`:

==========================================================  ===================================
what happened                                               raised
==========================================================  ===================================
connection refused / DNS / TLS / timeout / retries spent    ``DependencyUnavailable``
HTTP 5xx, 401/403, a body that is not Prometheus' JSON      ``DependencyUnavailable``
HTTP 400 / 422 (``bad_data``, ``execution``: a bad query)   ``InvalidSpec`` naming the field
                                                            (``spec.scaling.slo.query``) and
                                                            Prometheus' own error message
a range vector or a string where a number is needed         ``InvalidSpec`` (same field)
==========================================================  ===================================

An empty result, or ``NaN`` (``histogram_quantile`` over no samples), is not an error: it is
"no data", returned as ``None``, which the policy treats as missing metrics.
"""

from __future__ import annotations

import ast
import contextlib
import json
import math
import re
from collections.abc import Iterator
from typing import Any, Protocol

import requests
from prometheus_api_client import PrometheusConnect
from prometheus_api_client.exceptions import (
    MetricValueConversionError,
    PrometheusApiClientException,
)
from urllib3.util.retry import Retry

from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = [
    "QUERY_FIELD",
    "PrometheusClient",
    "PrometheusPort",
    "map_errors",
    "series_of",
    "value_of",
]

QUERY_FIELD = "spec.scaling.slo.query"
TIMEOUT_SECONDS = 5.0
_STATUS = re.compile(r"HTTP Status Code (\d+) \((.*)\)\s*$", re.DOTALL)


class PrometheusPort(Protocol):
    def query_value(self, promql: str, *, obj: str = "", field: str = QUERY_FIELD) -> float | None:
        """The query's value now (worst of several series), or ``None`` when there is no data.

        Raises ``DependencyUnavailable`` (Prometheus unreachable or failing) or ``InvalidSpec``
        (Prometheus rejected the query; ``obj`` and ``field`` say whose and where)."""
        ...


def _http_error(exc: PrometheusApiClientException) -> tuple[int, str]:
    """Status code and Prometheus' ``error`` text from the library's exception message."""
    match = _STATUS.match(str(exc))
    if not match:
        return 0, str(exc)
    status, raw = int(match.group(1)), match.group(2)
    try:
        content = ast.literal_eval(raw)
        text = content.decode("utf-8", "replace") if isinstance(content, bytes) else str(content)
    except (ValueError, SyntaxError):
        text = raw
    try:
        body = json.loads(text)
        if isinstance(body, dict) and body.get("error"):
            kind = body.get("errorType")
            return status, f"{kind}: {body['error']}" if kind else str(body["error"])
    except ValueError:
        pass
    return status, text.strip()[:500]


@contextlib.contextmanager
def map_errors(url: str, promql: str, obj: str = "", field: str = QUERY_FIELD) -> Iterator[None]:
    """Translate prometheus-api-client / requests errors into fogfleet errors."""
    try:
        yield
    except PrometheusApiClientException as exc:
        status, message = _http_error(exc)
        if status in (400, 422):
            raise InvalidSpec(
                obj or "PromQL", field, f"Prometheus rejected the query {promql!r}: {message}"
            ) from exc
        raise DependencyUnavailable(
            f"Prometheus at {url} answered HTTP {status or '?'}: {message}"
        ) from exc
    except requests.exceptions.RequestException as exc:  # connection, timeout, retries, JSON
        raise DependencyUnavailable(f"Cannot query Prometheus at {url}: {exc}") from exc
    except (KeyError, TypeError, ValueError, MetricValueConversionError) as exc:  # not its JSON
        raise DependencyUnavailable(
            f"Prometheus at {url} sent an unexpected answer: {exc!r}"
        ) from exc
    except OSError as exc:  # anything the socket layer raises outside requests' wrapping
        raise DependencyUnavailable(f"Cannot query Prometheus at {url}: {exc}") from exc


def _number(raw: Any, promql: str, obj: str, field: str) -> float:
    try:
        return float(raw)
    except (TypeError, ValueError):
        raise InvalidSpec(
            obj or "PromQL", field, f"the query {promql!r} returns {raw!r}, not a number"
        ) from None


def value_of(result: Any, promql: str, obj: str = "", field: str = QUERY_FIELD) -> float | None:
    """Reduce an instant-query result to one number (the maximum series), ``None`` if empty.

    ``result`` is ``data.result`` as prometheus-api-client returns it: a list of
    ``{"metric", "value": [t, "v"]}`` (vector), ``[t, "v"]`` (scalar) or series with
    ``values`` (a range vector, which an SLO cannot use)."""
    if isinstance(result, list) and len(result) == 2 and not isinstance(result[0], dict):
        values = [_number(result[1], promql, obj, field)]  # scalar or string
    elif isinstance(result, list):
        values = []
        for series in result:
            if "values" in series:
                raise InvalidSpec(
                    obj or "PromQL",
                    field,
                    f"the query {promql!r} returns a range vector; it must return one number "
                    "(wrap it in a function such as rate() or max_over_time())",
                )
            values.append(_number(series["value"][1], promql, obj, field))
    else:
        raise InvalidSpec(
            obj or "PromQL", field, f"the query {promql!r} returns a {type(result).__name__}"
        )
    finite = [v for v in values if not math.isnan(v)]
    return max(finite) if finite else None


def series_of(
    result: Any, promql: str, obj: str = "", field: str = QUERY_FIELD
) -> list[tuple[dict[str, str], float]]:
    """An instant vector as (labels, value) pairs; a scalar or range vector is refused."""
    if not isinstance(result, list) or (len(result) == 2 and not isinstance(result[0], dict)):
        raise InvalidSpec(obj or "PromQL", field, f"the query {promql!r} is not a vector")
    out = []
    for series in result:
        if "value" not in series:
            raise InvalidSpec(obj or "PromQL", field, f"the query {promql!r} is a range vector")
        value = _number(series["value"][1], promql, obj, field)
        if not math.isnan(value):
            out.append(({str(k): str(v) for k, v in series.get("metric", {}).items()}, value))
    return out


class PrometheusClient:
    """PrometheusPort over one ``PrometheusConnect`` (thread-safe enough: one Session per call
    path; requests' connection pool is)."""

    def __init__(
        self,
        url: str,
        *,
        timeout: float = TIMEOUT_SECONDS,
        retries: int = 1,
        session: requests.Session | None = None,
    ) -> None:
        self.url = url.rstrip("/")
        self.timeout = timeout
        # connect retries only: a refused connection fails in well under a second
        retry = Retry(total=retries, connect=retries, read=0, status=0, backoff_factor=0.1)
        with map_errors(self.url, "<connect>"):
            self._prom = PrometheusConnect(
                url=self.url, disable_ssl=True, retry=retry, session=session
            )

    def query_value(self, promql: str, *, obj: str = "", field: str = QUERY_FIELD) -> float | None:
        with map_errors(self.url, promql, obj, field):
            result = self._prom.custom_query(promql, timeout=self.timeout)
            return value_of(result, promql, obj, field)

    def query_series(
        self, promql: str, *, obj: str = "", field: str = QUERY_FIELD
    ) -> list[tuple[dict[str, str], float]]:
        """Every series of an instant vector query with its labels (NaN left out)."""
        with map_errors(self.url, promql, obj, field):
            result = self._prom.custom_query(promql, timeout=self.timeout)
            return series_of(result, promql, obj, field)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._prom.close()
