"""Conditions per Kubernetes' API conventions, on the bed (issue 38): every condition and the
status carry the ``observedGeneration`` they were computed for, so a spec change the operator
has not reconciled yet is visible, and the real ``kubectl wait --for=condition=Ready`` cannot
pass on the stale generation (kubectl's wait compares a condition's observedGeneration with
metadata.generation: pkg/cmd/wait/condition.go).

To see the lag without racing the operator, the operator is stopped while the spec changes:
Ready is still True, for generation 1, while the fleet is at generation 2, and ``kubectl wait``
times out. Started again, the operator catches up: the status and each condition say 2, and
``kubectl wait`` passes.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import Operator, apply_warehouse, fleet, install_crds, wait_ready

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the operator runs as a local process beside the bed"),
    pytest.mark.observability,
    pytest.mark.timeout(420),
]


@pytest.fixture
def operator(
    kube: Kube, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[Operator]:
    install_crds(kube)
    op = Operator(kube.kubeconfig, [namespace], tmp_path / "operator.log")
    diagnostics.append(lambda: ("operator log", op.logs(150)))
    op.start().wait_live()
    yield op
    op.stop()


def generations(obj: dict[str, Any]) -> dict[str, int | None]:
    status = obj.get("status") or {}
    out = {"status": status.get("observedGeneration")}
    out.update({c["type"]: c.get("observedGeneration") for c in status.get("conditions") or []})
    return out


def kubectl_wait_ready(kube: Kube, ns: str, timeout: str) -> bool:
    proc = kube.kubectl(
        "wait", "--for=condition=Ready", "robotfleet/warehouse", "-n", ns, f"--timeout={timeout}",
        check=False,
    )  # fmt: skip
    return proc.returncode == 0


def test_conditions_lag_a_spec_change_until_it_is_reconciled(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    apply_warehouse(kube, namespace)
    wait_ready(kube, namespace, timeout=240)
    before = fleet(kube, namespace)
    gen = before["metadata"]["generation"]
    assert set(generations(before).values()) == {gen}, generations(before)
    assert kubectl_wait_ready(kube, namespace, "10s")

    operator.stop()
    patch = {"spec": {"scheduler": {"seed": 7}}}
    kube.kubectl("patch", "robotfleet", "warehouse", "-n", namespace, "--type=merge",
                 "-p", json.dumps(patch))  # fmt: skip
    stale = fleet(kube, namespace)
    assert stale["metadata"]["generation"] == gen + 1
    ready = {c["type"]: c for c in stale["status"]["conditions"]}["Ready"]
    assert ready["status"] == "True" and ready["observedGeneration"] == gen
    assert not kubectl_wait_ready(kube, namespace, "5s"), "Ready of the old generation passed"

    operator.start().wait_live()
    kube.wait_for(
        "every condition at the new generation",
        lambda: set(generations(fleet(kube, namespace)).values()) == {gen + 1},
        180,
    )
    assert kubectl_wait_ready(kube, namespace, "180s")
    assert set(generations(fleet(kube, namespace)).values()) == {gen + 1}
