"""ExplanationRequests answered from the plan the operator holds (controllers/fleet/explain.py,
runtime/explanations.py): the operator's answer is the document the plugin computes from the
API's objects, on the same cluster."""

from __future__ import annotations

import asyncio
import math

import pytest

from fogfleet.commandline.kubectl.live import read_fleet
from fogfleet.controllers.fleet import explain
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.runtime.explanations import Explainer
from fogfleet.snapshot.live import why_doc, why_of

KEY = ("warehouse", "warehouse")
NOW = 1_800_000_000.0


def _request(module: str, robot: str | None = "robot-2", **status: object) -> dict:
    spec = {"fleet": "warehouse", "module": module, **({"robot": robot} if robot else {})}
    return {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "ExplanationRequest",
        "metadata": {"name": "why-abc", "namespace": "warehouse"},
        "spec": spec,
        **({"status": dict(status)} if status else {}),
    }


@pytest.fixture
def planned(kube, deps):
    """The warehouse fleet planned, rolled out and refreshed (its status lists the placement)."""
    reconcile(kube.get_fleet(*KEY), deps)
    kube.run_pods()
    reconcile(kube.get_fleet(*KEY), deps)
    return deps


@pytest.mark.parametrize("module", ["scene-segmentation", "nav-controller"])
def test_the_operator_answers_with_the_document_the_plugin_computes(kube, planned, module):
    status = explain.answer(kube, planned.store, _request(module), NOW)
    assert status["phase"] == "Answered" and status["answeredTime"]
    local = why_doc(why_of(read_fleet(kube, *KEY), module, "robot-2"))
    assert status["explanation"] == local
    assert status["explanation"]["instances"][0]["alternatives"]  # something to compare
    assert status["planGeneration"] == 1


def test_every_robot_up_to_the_limit(kube, planned):
    request = _request("scene-segmentation", robot=None)
    request["spec"]["limit"] = 2
    doc = explain.answer(kube, planned.store, request, NOW)["explanation"]
    assert len(doc["instances"]) == 2 and doc["omittedInstances"] == 3


def test_a_rate_measured_after_the_plan_is_the_one_answered(kube, planned):
    kube.fleets[KEY]["status"]["measured"] = [
        {"module": "scene-segmentation", "measuredMissRate": 0.125}
    ]
    status = explain.answer(kube, planned.store, _request("scene-segmentation"), NOW)
    assert status["explanation"]["measuredMissRate"] == 0.125


def test_no_plan_held_is_failed_with_the_reason_the_plugin_falls_back_on(kube, deps):
    status = explain.answer(kube, deps.store, _request("scene-segmentation"), NOW)
    assert (status["phase"], status["reason"]) == ("Failed", "NoPlanHeld")
    assert "warehouse/warehouse" in status["message"]


def test_an_unknown_module_or_a_deleted_fleet_is_failed_with_its_reason(kube, planned):
    status = explain.answer(kube, planned.store, _request("no-such-module"), NOW)
    assert (status["phase"], status["reason"]) == ("Failed", "InvalidRequest")
    assert "no-such-module" in status["message"]
    bad = _request("scene-segmentation")
    bad["spec"]["limit"] = 0
    status = explain.answer(kube, planned.store, bad, NOW)
    assert status["reason"] == "InvalidRequest" and "spec.limit" in status["message"]
    del kube.fleets[KEY]
    status = explain.answer(kube, planned.store, _request("scene-segmentation"), NOW)
    assert status["reason"] == "FleetNotFound"


def test_numbers_json_cannot_carry_become_null() -> None:
    assert explain._finite({"a": [1.0, math.nan], "b": math.inf, "c": "x"}) == {
        "a": [1.0, None],
        "b": None,
        "c": "x",
    }


def test_a_new_request_is_answered_once_and_an_old_answer_expires(kube, planned, monkeypatch):
    explainer = Explainer(kube, planned.store)
    asyncio.run(explainer.event(_request("scene-segmentation"), "ADDED"))
    ((ns, name, status),) = kube.explanations
    assert (ns, name, status["phase"]) == ("warehouse", "why-abc", "Answered")
    # the answer's own MODIFIED event answers nothing again; it expires after the TTL
    monkeypatch.setattr("fogfleet.runtime.explanations.REQUEST_TTL_SECONDS", 0.0)

    async def answered_then_expired() -> None:
        await explainer.event(_request("scene-segmentation", **status), "MODIFIED")
        for _ in range(1000):  # the delete runs on a thread: up to 10 s on a loaded machine
            await asyncio.sleep(0.01)
            if kube.deleted:
                return

    asyncio.run(answered_then_expired())
    assert len(kube.explanations) == 1
    assert kube.deleted == ["ExplanationRequest/warehouse/why-abc"]


def test_an_answer_too_large_for_an_object_is_failed_so_the_asker_explains(
    kube, planned, monkeypatch
):
    monkeypatch.setattr(explain, "ANSWER_BYTES", 2048)
    request = _request("scene-segmentation", robot=None)
    status = explain.answer(kube, planned.store, request, NOW)
    assert (status["phase"], status["reason"]) == ("Failed", "TooLarge")
    assert "KiB" in status["message"] and "--robot" in status["message"]
    assert "explanation" not in status
