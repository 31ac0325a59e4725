"""``kubectl fogfleet why`` asks the operator first (an ExplanationRequest) and explains by
itself only when the operator cannot answer."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import pytest

from fogfleet.commandline.kubectl.cli import main
from fogfleet.errors import DependencyUnavailable

from .test_plugin import FakeCluster

Obj = dict[str, Any]
ANSWER = {"fleet": "warehouse/warehouse", "module": "nav-controller", "instances": []}


class Asked(FakeCluster):
    """The fixed objects, an operator that answers with ``status`` (or raises ``error``), and
    a count of the lists the plugin made."""

    def __init__(self, status: Obj | None = None, error: Exception | None = None) -> None:
        super().__init__()
        self.status, self.error = status, error
        self.asked: list[tuple[str, Obj, float]] = []
        self.lists = 0

    def ask_explanation(self, namespace: str, spec: Mapping[str, Any], seconds: float) -> Any:
        self.asked.append((namespace, dict(spec), seconds))
        if self.error is not None:
            raise self.error
        return None if self.status is None else {"status": self.status}

    def list_compute_nodes(self) -> list[Obj]:
        self.lists += 1
        return super().list_compute_nodes()


def _why(cluster: Asked, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str, str]:
    argv = ["why", "warehouse", "nav-controller", "--robot", "robot-3", "-o", "json", *extra]
    code = main(argv, connect=lambda kubeconfig, context: (cluster, "warehouse"))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_operators_answer_is_printed_and_nothing_is_listed(capsys) -> None:
    cluster = Asked({"phase": "Answered", "explanation": ANSWER, "sharedNodes": "edge-1: 2 cores"})
    code, out, err = _why(cluster, capsys, "--wait", "2.5", "--limit", "7")
    assert code == 0 and json.loads(out) == ANSWER
    assert "Shared nodes of warehouse/warehouse: edge-1: 2 cores" in err
    ns, spec, seconds = cluster.asked[0]
    assert (ns, seconds) == ("warehouse", 2.5)
    asked = {"fleet": "warehouse", "module": "nav-controller", "robot": "robot-3", "limit": 7}
    assert spec == asked
    assert cluster.lists == 0


@pytest.mark.parametrize(
    ("status", "error", "said"),
    [
        (None, None, "no answer within 5 s"),
        ({"phase": "Failed", "reason": "NoPlanHeld", "message": "holds no plan"}, None, "no plan"),
        ({"phase": "Failed", "reason": "TooLarge", "message": "take 900 KiB"}, None, "900 KiB"),
        (None, DependencyUnavailable("Cannot ask: forbidden; check the RBAC"), "forbidden"),
    ],
)
def test_without_an_answer_it_explains_by_itself_and_says_why(capsys, status, error, said) -> None:
    cluster = Asked(status, error)
    code, out, err = _why(cluster, capsys)
    assert code == 0 and cluster.lists == 1
    doc = json.loads(out)
    assert doc["instances"][0]["instance"] == "robot-3/nav-controller"
    assert "The operator did not explain" in err and said in err


def test_a_request_the_operator_finds_invalid_exits_2_without_explaining(capsys) -> None:
    status = {"phase": "Failed", "reason": "InvalidRequest", "message": "has no instance of x"}
    cluster = Asked(status)
    code, _, err = _why(cluster, capsys)
    assert code == 2 and "has no instance of x" in err and cluster.lists == 0


def test_local_never_asks(capsys) -> None:
    cluster = Asked({"phase": "Answered", "explanation": ANSWER})
    code, out, _ = _why(cluster, capsys, "--local")
    assert code == 0 and not cluster.asked and json.loads(out) != ANSWER
