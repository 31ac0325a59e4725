"""The scaling controller and the Prometheus adapter, with fake ports (no cluster, no network)."""

from __future__ import annotations

import copy
import inspect
import itertools
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest
import requests
import yaml
from prometheus_api_client import exceptions as prom_exceptions

from fogfleet.adapters.prometheus import QUERY_FIELD, PrometheusClient, value_of
from fogfleet.api.loader import parse_object
from fogfleet.autoscaling.behavior import BehaviorState, Recommendation, ScaleEvent
from fogfleet.autoscaling.policy import MetricsSnapshot, ScalerState
from fogfleet.autoscaling.pools import pools_for, service_rate
from fogfleet.autoscaling.state import ANNOTATION_STATE, dump_state, load_state
from fogfleet.controllers.module.scaling import ScalingDeps, reconcile_scaling
from fogfleet.errors import DependencyUnavailable, InvalidSpec

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "manifests" / "examples" / "shared-detector" / "modules.yaml"
Obj = dict[str, Any]


# --------------------------------------------------------------------------- Prometheus adapter


class FakeResponse:
    def __init__(self, status: int, body: bytes) -> None:
        self.status_code = status
        self.content = body

    def json(self) -> Any:
        try:
            return json.loads(self.content)
        except ValueError as exc:
            raise requests.exceptions.JSONDecodeError(str(exc), "", 0) from exc


class FakeSession(requests.Session):
    """A requests.Session whose request() returns or raises what the test says."""

    def __init__(self, answer: Callable[[], Any]) -> None:
        super().__init__()
        self.answer = answer
        self.queries: list[str] = []

    def request(self, method: str, url: str, **kwargs: Any) -> Any:  # type: ignore[override]
        self.queries.append(kwargs.get("params", {}).get("query", ""))
        return self.answer()


def client(answer: Callable[[], Any]) -> PrometheusClient:
    return PrometheusClient("http://127.0.0.1:9", session=FakeSession(answer))


def ok(result: Any, result_type: str = "vector") -> Callable[[], FakeResponse]:
    body = {"status": "success", "data": {"resultType": result_type, "result": result}}
    return lambda: FakeResponse(200, json.dumps(body).encode())


def raise_(exc: BaseException) -> Callable[[], Any]:
    def fn() -> Any:
        raise exc

    return fn


REQUEST_ERRORS = sorted(
    (
        cls
        for _, cls in inspect.getmembers(requests.exceptions, inspect.isclass)
        if issubclass(cls, requests.exceptions.RequestException)
    ),
    key=lambda c: c.__name__,
)


@pytest.mark.parametrize("cls", REQUEST_ERRORS, ids=lambda c: c.__name__)
def test_every_requests_error_means_prometheus_is_unavailable(cls: type[Exception]) -> None:
    try:
        exc = cls("boom")
    except TypeError:  # JSONDecodeError needs (msg, doc, pos)
        exc = cls("boom", "", 0)
    with pytest.raises(DependencyUnavailable, match=r"127\.0\.0\.1:9"):
        client(raise_(exc)).query_value("up")


@pytest.mark.parametrize(
    "exc",
    [ConnectionRefusedError("refused"), TimeoutError("slow"), OSError("no route")],
    ids=lambda e: type(e).__name__,
)
def test_socket_errors_outside_requests_are_mapped(exc: Exception) -> None:
    with pytest.raises(DependencyUnavailable):
        client(raise_(exc)).query_value("up")


def test_every_prometheus_api_client_exception_is_mapped() -> None:
    classes = [
        c
        for _, c in inspect.getmembers(prom_exceptions, inspect.isclass)
        if issubclass(c, Exception)
    ]
    assert classes
    for cls in classes:
        with pytest.raises((DependencyUnavailable, InvalidSpec)):
            client(raise_(cls("HTTP Status Code 500 (b'oops')"))).query_value("up")


def test_bad_query_names_the_field_and_prometheus_message() -> None:
    body = json.dumps(
        {
            "status": "error",
            "errorType": "bad_data",
            "error": 'invalid parameter "query": 1:16: parse error: unclosed left parenthesis',
        }
    ).encode()
    prom = client(lambda: FakeResponse(400, body))
    with pytest.raises(InvalidSpec) as info:
        prom.query_value("sum(rate(x[1m]", obj="SoftwareModule/detector")
    err = info.value
    assert err.obj == "SoftwareModule/detector"
    assert err.field == QUERY_FIELD == "spec.scaling.slo.query"
    assert "unclosed left parenthesis" in err.message
    assert "sum(rate(x[1m]" in err.message


def test_execution_error_422_is_a_bad_query_too() -> None:
    body = b'{"status":"error","errorType":"execution","error":"many-to-many matching"}'
    with pytest.raises(InvalidSpec, match="many-to-many"):
        client(lambda: FakeResponse(422, body)).query_value("a / b")


@pytest.mark.parametrize("status", [401, 403, 500, 502, 503, 504])
def test_server_side_failures_are_unavailability(status: int) -> None:
    with pytest.raises(DependencyUnavailable, match=str(status)):
        client(lambda: FakeResponse(status, b"down")).query_value("up")


@pytest.mark.parametrize("body", [b"<html>proxy</html>", b'{"status":"success"}', b"[]"])
def test_an_answer_that_is_not_prometheus_json_is_unavailability(body: bytes) -> None:
    with pytest.raises(DependencyUnavailable):
        client(lambda: FakeResponse(200, body)).query_value("up")


def test_no_data_and_nan_are_none_not_errors() -> None:
    assert client(ok([])).query_value("up") is None
    assert client(ok([{"metric": {}, "value": [1, "NaN"]}])).query_value("up") is None


def test_several_series_give_the_worst_and_a_scalar_its_value() -> None:
    series = [
        {"metric": {"tier": t}, "value": [1, v]} for t, v in (("edge", "0.2"), ("cloud", "0.4"))
    ]
    assert client(ok(series)).query_value("x") == pytest.approx(0.4)
    assert client(ok([1, "2.5"], "scalar")).query_value("scalar(x)") == 2.5


def test_range_vectors_and_strings_are_bad_queries() -> None:
    with pytest.raises(InvalidSpec, match="range vector"):
        value_of([{"metric": {}, "values": [[1, "1"]]}], "x[1m]")
    with pytest.raises(InvalidSpec, match="not a number"):
        client(ok([1, "abc"], "string")).query_value('"abc"')


def test_series_keep_their_labels_and_leave_nan_out() -> None:
    series = [
        {"metric": {"node": "robot-1"}, "value": [1, "0.5"]},
        {"metric": {"node": "robot-2"}, "value": [1, "NaN"]},
    ]
    assert client(ok(series)).query_series("up") == [({"node": "robot-1"}, 0.5)]
    assert client(ok([])).query_series("up") == []


def test_series_of_a_scalar_or_a_range_vector_is_a_bad_query() -> None:
    with pytest.raises(InvalidSpec, match="not a vector"):
        client(ok([1, "2"], "scalar")).query_series("scalar(up)", field="status.links")
    with pytest.raises(InvalidSpec, match="range vector"):
        client(ok([{"metric": {}, "values": [[1, "1"]]}], "matrix")).query_series("up[1m]")
    with pytest.raises(DependencyUnavailable):
        client(raise_(requests.exceptions.ConnectionError("refused"))).query_series("up")


# --------------------------------------------------------------------------- fakes


class FakeProm:
    """Answers by substring of the query; an Exception value is raised."""

    def __init__(self, answers: Mapping[str, float | Exception | None] | None = None) -> None:
        self.answers: dict[str, float | Exception | None] = dict(answers or {})
        self.queries: list[str] = []

    def query_value(self, promql: str, *, obj: str = "", field: str = QUERY_FIELD) -> float | None:
        self.queries.append(promql)
        for key, value in self.answers.items():
            if key in promql:
                if isinstance(value, Exception):
                    if isinstance(value, InvalidSpec):
                        raise InvalidSpec(obj, field, value.message)
                    raise value
                return value
        return None


class FakeKube:
    def __init__(self, module: Obj) -> None:
        self.module = copy.deepcopy(module)
        self.pods: list[Obj] = []
        self.status_patches: list[Obj] = []
        self.events: list[tuple[str, str, str]] = []

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return [
            p
            for p in self.pods
            if all(p["metadata"]["labels"].get(k) == v for k, v in selector.items())
        ]

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        self.status_patches.append(copy.deepcopy(dict(status)))
        merged = dict(self.module.get("status") or {})
        merged.update({k: v for k, v in status.items()})
        self.module["status"] = merged

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None:
        self.module["metadata"].setdefault("annotations", {}).update(annotations)

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None:
        self.events.append((type_, reason, message))

    def set_pods(self, module: str, **tiers: int) -> None:
        self.pods = [
            {
                "metadata": {
                    "name": f"{module}-{tier}-{k}",
                    "labels": {
                        "fogfleet.io/module": module,
                        "fogfleet.io/tier": tier,
                        "app.kubernetes.io/managed-by": "fogfleet",
                    },
                },
                "status": {"phase": "Running", "conditions": [{"type": "Ready", "status": "True"}]},
            }
            for tier, n in tiers.items()
            for k in range(n)
        ]


def example_module(**scaling: Any) -> Obj:
    doc = next(d for d in yaml.safe_load_all(EXAMPLE.read_text()) if d["spec"].get("scaling"))
    doc["metadata"].update(generation=1, uid="uid-1")
    doc["spec"]["scaling"].update(scaling)
    return doc


def reactive_module(**scaling: Any) -> Obj:
    base = {
        "mode": "reactive",
        "behavior": {
            "scaleUp": {"stabilizationWindowSeconds": 0,
                        "policies": [{"type": "Pods", "value": 4, "periodSeconds": 10}]},
            "scaleDown": {"stabilizationWindowSeconds": 30,
                          "policies": [{"type": "Pods", "value": 1, "periodSeconds": 10}]},
        },
    }  # fmt: skip
    return example_module(**{**base, **scaling})


def conds(kube: FakeKube) -> dict[str, Obj]:
    return {c["type"]: c for c in kube.module["status"]["conditions"]}


def pools(kube: FakeKube) -> dict[str, int]:
    return {p["tier"]: p["replicas"] for p in kube.module["status"]["scaling"]["pools"]}


def run(kube: FakeKube, prom: FakeProm, now: float, **deps: Any) -> Any:
    return reconcile_scaling(kube.module, ScalingDeps(kube, prom, **deps), now)


# --------------------------------------------------------------------------- pure parts


def test_pools_follow_the_spec_edge_first_private_on_the_edge_only() -> None:
    mod = parse_object(example_module())
    edge, cloud = pools_for(mod)  # type: ignore[arg-type]
    assert (edge.name, edge.max_replicas, edge.setup_seconds, edge.accepts_private) == (
        "edge", 17, 1.8, True,
    )  # fmt: skip
    assert (cloud.name, cloud.max_replicas, cloud.setup_seconds, cloud.accepts_private) == (
        "cloud", 19, 4.7, False,
    )  # fmt: skip
    assert edge.target_seconds == 0.35 and cloud.target_seconds == 0.5
    assert edge.percentile == 0.99 and edge.min_replicas == 1
    assert service_rate(mod) == pytest.approx(1 / 0.150)  # type: ignore[arg-type]
    assert cloud.network_delay_seconds > edge.network_delay_seconds > 0


def test_state_survives_a_round_trip_through_the_annotation() -> None:
    state = ScalerState(
        {"edge": BehaviorState((Recommendation(10.0, 3),), (ScaleEvent(10.0, 2),))},
        None,
        MetricsSnapshot(10.0, (), 4.5, 12.0),
    )
    back = load_state(dump_state(state), None)
    assert back.behavior == state.behavior
    assert back.previous is not None and back.previous.private_rate == 4.5
    assert load_state("{not json", None).behavior == {}


# --------------------------------------------------------------------------- reconcile


def test_slo_over_target_scales_up_and_says_why() -> None:
    kube = FakeKube(reactive_module())
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm({'tier="edge"': 0.7, 'tier="cloud"': 0.2})  # edge p99 at twice its target
    out = run(kube, prom, 1000.0)
    assert out.changed and out.metrics_available
    assert pools(kube) == {"edge": 4, "cloud": 1}
    scaling = kube.module["status"]["scaling"]
    assert scaling["desiredReplicas"] == 5 and scaling["metricsAvailable"] is True
    assert scaling["lastScaleTime"] == scaling["lastDecisionTime"]
    assert scaling["observedSloMillis"] == pytest.approx(700)
    c = conds(kube)
    assert c["Scaling"]["status"] == "True" and c["Scaling"]["reason"] == "ScaledUp"
    assert c["MetricsUnavailable"]["status"] == "False"
    assert [e[1] for e in kube.events] == ["ScaledUp"]
    assert "edge 2 -> 4" in kube.events[0][2]
    assert len(kube.status_patches) == 1  # status and conditions in one patch
    assert ANNOTATION_STATE in kube.module["metadata"]["annotations"]


def test_scale_down_waits_for_the_window_then_goes_at_the_policy_rate() -> None:
    kube = FakeKube(reactive_module())
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm({'tier="edge"': 1.4, 'tier="cloud"': 0.2})
    run(kube, prom, 0.0)  # edge 2 -> 6 (4 pods per 10 s)
    kube.set_pods("object-detector", edge=6, cloud=1)
    run(kube, prom, 10.0)
    high = pools(kube)["edge"]
    assert high > 2
    prom.answers['tier="edge"'] = 0.01  # load gone
    seen = []
    for t in range(20, 100, 5):
        kube.set_pods("object-detector", edge=pools(kube)["edge"], cloud=1)
        run(kube, prom, float(t))
        seen.append((t, pools(kube)["edge"]))
    assert all(n == high for t, n in seen if t < 10 + 30)  # 30 s stabilisation window
    drops = [(a[1] - b[1]) for a, b in itertools.pairwise(seen) if b[1] < a[1]]
    assert drops and max(drops) <= 1  # Pods policy: at most 1 per 10 s
    first_drop = next(t for t, n in seen if n < high)
    assert first_drop >= 40
    assert pools(kube)["edge"] >= 1  # never below minReplicas


def test_prometheus_down_holds_and_says_why_then_resumes() -> None:
    kube = FakeKube(reactive_module())
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm({'tier="edge"': 0.7, 'tier="cloud"': 0.2})
    run(kube, prom, 0.0)
    before = pools(kube)
    prom.answers = {"": DependencyUnavailable("Cannot query Prometheus at http://x: refused")}
    out = run(kube, prom, 15.0)
    assert not out.changed and not out.metrics_available
    assert pools(kube) == before
    c = conds(kube)
    assert c["MetricsUnavailable"]["status"] == "True"
    assert c["MetricsUnavailable"]["reason"] == "PrometheusUnreachable"
    assert "refused" in c["MetricsUnavailable"]["message"]
    assert c["Scaling"]["status"] == "False"
    assert kube.module["status"]["scaling"]["metricsAvailable"] is False
    run(kube, prom, 30.0)  # still down: no second warning Event
    assert [e[1] for e in kube.events].count("MetricsUnavailable") == 1
    prom.answers = {'tier="edge"': 1.4, 'tier="cloud"': 0.2}
    out = run(kube, prom, 45.0)
    assert out.metrics_available and out.changed
    assert conds(kube)["MetricsUnavailable"]["status"] == "False"


def test_no_data_holds_and_is_not_an_error() -> None:
    kube = FakeKube(reactive_module())
    out = run(kube, FakeProm(), 0.0)
    assert out.problem == "NoData" and not out.changed
    assert conds(kube)["MetricsUnavailable"]["reason"] == "NoData"
    assert pools(kube) == {"edge": 2, "cloud": 1}  # spec.replicas on the edge, cloud at min


def test_bad_query_is_reported_precisely_and_nothing_scales() -> None:
    kube = FakeKube(reactive_module(slo={"query": "sum(rate(x[1m]", "targetMillis": 350}))
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm({"sum(rate(x": InvalidSpec("", "", "bad_data: parse error: unclosed left")})
    out = run(kube, prom, 0.0)
    assert out.problem == "InvalidSLOQuery" and not out.changed
    c = conds(kube)["MetricsUnavailable"]
    assert c["status"] == "True" and c["reason"] == "InvalidSLOQuery"
    assert "unclosed left" in c["message"]
    warnings = [e for e in kube.events if e[1] == "InvalidSLOQuery"]
    assert len(warnings) == 1 and warnings[0][0] == "Warning"
    assert not any(e[1].startswith("Scaled") for e in kube.events)


def test_safety_relevant_module_never_goes_to_zero() -> None:
    kube = FakeKube(reactive_module(minReplicas=0, pools=[{"tier": "edge", "maxReplicas": 5}]))
    kube.set_pods("object-detector", edge=2)
    prom = FakeProm({'tier="edge"': 0.0001})
    for t in range(0, 400, 15):
        run(kube, prom, float(t))
        kube.set_pods("object-detector", edge=pools(kube)["edge"])
    assert pools(kube)["edge"] == 1


def test_predictive_sizes_from_the_offered_rates() -> None:
    kube = FakeKube(example_module(behavior={"scaleUp": {"stabilizationWindowSeconds": 0}}))
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm(
        {"count(": 4.0, 'privacy="private"': 27.0, 'privacy="normal"': 63.0, "histogram": 0.3}
    )
    out = run(kube, prom, 0.0, period_seconds=5.0, rate_window_seconds=5)
    assert out.metrics_available
    assert sum(out.replicas.values()) > 3 and out.replicas["edge"] >= out.replicas["cloud"]
    assert "sized for" in kube.module["status"]["scaling"]["reason"]
    assert kube.module["status"]["scaling"]["observedSloMillis"] == pytest.approx(300)
    # the admission forecast (tinyKube III-B) of the decided pools: the first step is rate
    # limited (tinykube preset), so it still rejects; once the pools have grown, both classes
    # are within the 5 % the p95 target allows
    first = kube.module["status"]["scaling"]["predictedPrivateRejected"]
    for t in range(5, 300, 5):
        kube.set_pods("object-detector", **pools(kube))
        run(kube, prom, float(t), period_seconds=5.0, rate_window_seconds=5)
    scaling = kube.module["status"]["scaling"]
    assert scaling["predictedPrivateRejected"] <= 0.05 < first
    assert scaling["predictedNormalRejected"] <= 0.05


def test_predictive_without_samples_holds() -> None:
    kube = FakeKube(example_module())
    out = run(kube, FakeProm({"count(": None, "privacy": 0.0}), 0.0)
    assert out.problem == "NoData" and not out.changed


def test_restart_keeps_the_stabilisation_memory() -> None:
    kube = FakeKube(reactive_module())
    kube.set_pods("object-detector", edge=2, cloud=1)
    prom = FakeProm({'tier="edge"': 1.4, 'tier="cloud"': 0.2})
    run(kube, prom, 0.0)
    kube.set_pods("object-detector", edge=pools(kube)["edge"], cloud=1)
    high = pools(kube)["edge"]
    # a "new operator process": only the object (status + annotation) carries the memory
    kube2 = FakeKube(kube.module)
    kube2.pods = kube.pods
    prom.answers['tier="edge"'] = 0.01
    run(kube2, prom, 10.0)
    assert pools(kube2)["edge"] == high  # still inside the 30 s scale-down window


def test_other_conditions_of_the_module_are_kept() -> None:
    body = reactive_module()
    body["status"] = {"conditions": [{"type": "Ready", "status": "True", "reason": "Placed"}]}
    kube = FakeKube(body)
    run(kube, FakeProm({"tier": 0.1}), 0.0)
    assert set(conds(kube)) == {"Ready", "Scaling", "MetricsUnavailable"}


def test_module_without_scaling_or_with_another_backend_is_skipped() -> None:
    body = example_module(mode="reactive", backend="hpa")
    out = run(FakeKube(body), FakeProm(), 0.0)
    assert out.skipped
    assert not math.isnan(0.0)


# --------------------------------------------------------------------------- HPA / KEDA renderer


def test_keda_scaled_object_carries_the_slo_query_bounds_and_tinykube_behaviour() -> None:
    from fogfleet.api.v1alpha1.scaling import load_scaling_spec
    from fogfleet.render.scaling import render_scaled_object

    spec = load_scaling_spec(
        "SoftwareModule/det",
        {"maxReplicas": 36, "backend": "keda", "behavior": {"preset": "tinykube"},
         "slo": {"metric": "responseTime", "targetMillis": 350, "percentile": 99}},
    )  # fmt: skip
    obj = render_scaled_object(
        spec,
        fleet="f",
        module="det",
        namespace="fleet",
        target="det",
        prometheus_url="http://prom:9090",
    )
    trigger = obj["spec"]["triggers"][0]
    assert trigger["type"] == "prometheus" and trigger["metricType"] == "Value"
    assert trigger["metadata"]["threshold"] == "0.35"
    assert 'module="det"' in trigger["metadata"]["query"]
    assert "histogram_quantile(0.99" in trigger["metadata"]["query"]
    behavior = obj["spec"]["advanced"]["horizontalPodAutoscalerConfig"]["behavior"]
    assert behavior["scaleUp"] == {
        "stabilizationWindowSeconds": 60,
        "selectPolicy": "Max",
        "policies": [{"type": "Percent", "value": 100, "periodSeconds": 30}],
    }
    assert behavior["scaleDown"]["stabilizationWindowSeconds"] == 300
    assert (obj["spec"]["minReplicaCount"], obj["spec"]["maxReplicaCount"]) == (1, 36)


def test_hpa_uses_cpu_or_an_external_slo_metric() -> None:
    from fogfleet.api.v1alpha1.scaling import load_scaling_spec
    from fogfleet.render.scaling import render_hpa

    cpu = load_scaling_spec(
        "m", {"maxReplicas": 5, "backend": "hpa", "targetCpuUtilizationPercent": 80}
    )
    hpa = render_hpa(cpu, fleet="f", module="det", namespace="fleet", target="det")
    assert hpa["spec"]["metrics"][0]["resource"]["target"]["averageUtilization"] == 80
    slo = load_scaling_spec(
        "m", {"maxReplicas": 5, "backend": "hpa", "slo": {"query": "x", "targetMillis": 350}}
    )
    ext = render_hpa(slo, fleet="f", module="det", namespace="fleet", target="det")
    ext = ext["spec"]["metrics"][0]
    assert ext["type"] == "External" and ext["external"]["target"] == {
        "type": "Value",
        "value": "350m",
    }
