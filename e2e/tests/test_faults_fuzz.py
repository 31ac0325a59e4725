"""Fuzzed CRs against the real API server and a running operator (issue 37, item 7).

Objects drawn from the CRDs' schemas (e2e/fuzz/strategies.py), whole and with one field
broken, go to the API server as server-side dry runs (python client, ``dry_run="All"``):
each one our validation refuses for a structural reason (a broken field) is refused with 422
and a field path; each one our validation accepts is accepted. Then a handful of objects the
API server stores but our validation refuses are created for real next to a good fleet: the
running operator reports them and keeps the good fleet Ready, and never exits.

    pytest e2e/tests/test_faults_fuzz.py --with-e2e -m faults
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import Operator, example_docs, wait_ready
from e2e.fuzz.strategies import KINDS, custom_resources, mutated_resources
from fogfleet.api.loader import parse_object
from fogfleet.errors import InvalidSpec

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.faults,
    pytest.mark.bed("a running local operator on the bed's API server"),
    pytest.mark.timeout(300),
]

GROUP, VERSION = "fogfleet.io", "v1alpha1"
PLURAL = {"ComputeNode": "computenodes", "SoftwareModule": "softwaremodules",
          "RobotFleet": "robotfleets"}  # fmt: skip


def _create(api: Any, doc: dict[str, Any], namespace: str, dry_run: str | None) -> None:
    plural = PLURAL[doc["kind"]]
    if doc["kind"] == "ComputeNode":
        api.create_cluster_custom_object(GROUP, VERSION, plural, doc, dry_run=dry_run)
    else:
        api.create_namespaced_custom_object(GROUP, VERSION, namespace, plural, doc,
                                            dry_run=dry_run)  # fmt: skip


def _ours(doc: dict[str, Any]) -> InvalidSpec | None:
    try:
        parse_object(doc)
    except InvalidSpec as exc:
        return exc
    return None


def test_the_api_server_refuses_broken_fields_with_a_path(kube: Kube, crds: None,
                                                          namespace: str) -> None:  # fmt: skip
    from kubernetes import client
    from kubernetes.client.exceptions import ApiException

    api = client.CustomObjectsApi(kube.api_client())
    seen = {"refused": 0, "accepted": 0, "ours-only": 0}

    @settings(max_examples=200, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(
        case=st.sampled_from(sorted(KINDS)).flatmap(
            lambda k: st.one_of(custom_resources(k).map(lambda o: (o, None)), mutated_resources(k))
        )
    )
    def check(case: tuple[dict[str, Any], str | None]) -> None:
        doc, broken = case
        ours = _ours(doc)
        try:
            _create(api, doc, namespace, "All")
            refused = None
        except ApiException as exc:
            refused = exc
        where = f"{doc['kind']}/{doc['metadata']['name']} ({broken})"
        if refused is not None:
            assert refused.status == 422, f"{where}: {refused.status} {refused.body}"
            causes = json.loads(refused.body).get("details", {}).get("causes", [])
            fields = [c.get("field", "") for c in causes]
            assert any(f.startswith(("spec", "metadata")) for f in fields), (
                f"{where}: no field path: {refused.body}"
            )
            assert ours is not None, (
                f"{where}: the API server refused what we accept: {refused.body}"
            )
            seen["refused"] += 1
        elif ours is None:
            seen["accepted"] += 1
        else:
            seen["ours-only"] += 1  # the operator must report these (the next test)

    check()
    print(f"\nfuzzed objects sent to the API server: {sum(seen.values())} {seen}")
    assert seen["refused"] > 0 and seen["accepted"] > 0, seen


def _stored_but_ours_refused(n: int) -> list[dict[str, Any]]:
    """SoftwareModules the API server stores and our validation refuses (a volume without a
    source, say), drawn until ``n`` are found."""
    found: list[dict[str, Any]] = []

    @settings(max_examples=300, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(doc=custom_resources("SoftwareModule"))
    def collect(doc: dict[str, Any]) -> None:
        if len(found) < n and _ours(doc) is not None:
            found.append(doc)

    collect()
    return found


def test_the_operator_reports_what_it_refuses_and_keeps_reconciling(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    from kubernetes import client
    from kubernetes.client.exceptions import ApiException

    docs = example_docs("single-robot", namespace)
    kube.apply(docs, namespace=namespace)
    wait_ready(kube, namespace, "single-robot", timeout=240)
    api = client.CustomObjectsApi(kube.api_client())
    stored: list[dict[str, Any]] = []
    for doc in _stored_but_ours_refused(8):
        doc["metadata"]["name"] = f"fuzz-{len(stored)}"
        try:
            _create(api, doc, namespace, None)
            stored.append(doc)
        except ApiException:
            continue  # a CEL rule refused it: the first test's business
    if not stored:
        # the CRD refused every module our validation refuses (the better outcome): the fleet
        # then names modules that do not exist, which the operator must report the same way
        stored = [{"metadata": {"name": f"fuzz-{k}"}} for k in range(3)]
        print("\nthe API server refused every drawn module our validation refuses; "
              "checking dangling module references instead")  # fmt: skip
    fleet = next(d for d in docs if d["kind"] == "RobotFleet")
    fleet["spec"]["modules"] = [*fleet["spec"]["modules"], *({"name": d["metadata"]["name"]}
                                                           for d in stored)]  # fmt: skip
    kube.apply(fleet, namespace=namespace)

    def reported() -> bool:
        out = kube.kubectl("get", "events", "-n", namespace, "-o",
                           "custom-columns=R:.reason,M:.message", check=False).stdout  # fmt: skip
        return any("fuzz-" in line for line in out.splitlines())

    # generous (a reconcile and one Event): only guards a hang
    kube.wait_for("an Event naming a refused module", reported, 60, interval=2)
    assert operator.proc is not None and operator.proc.poll() is None, operator.logs()
    assert "Traceback" not in operator.logs(400), operator.logs(400)
    # the good fleet, without them, is reconciled again and stays Ready
    fleet["spec"]["modules"] = [m for m in fleet["spec"]["modules"]
                                if not m["name"].startswith("fuzz-")]  # fmt: skip
    kube.apply(fleet, namespace=namespace)
    wait_ready(kube, namespace, "single-robot", timeout=120)
    assert operator.proc.poll() is None, operator.logs()
