"""The real operator (``fogfleet.runtime.handlers`` on kopf, our KubeClient and watch caches) run by
``kopf.testing.KopfRunner`` against the fake API server of :mod:`fakeapi`.

It checks the operator's behaviour on the wire: which objects it server-side applies and how it
patches the fleet's status, not how the controllers get there. Off in this run: the Prometheus
loops (no FOGFLEET_PROMETHEUS_URL), leader election (no Lease), peering (standalone), and the
liveness and metrics ports (0), none of which the fake serves.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import kopf
import pytest
import yaml
from kopf.testing import KopfRunner

from fogfleet.api.labels import LABEL_MODULE, LABEL_ROBOT
from fogfleet.runtime.handlers import register
from fogfleet.runtime.main import build_runtime
from fogfleet.settings import Settings

from .fakeapi import FakeApi

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "manifests" / "examples"
NS = "single-robot"
MODULES = 8  # the warehouse's modules, on the one robot of the single-robot fleet
# and its robot's discovery server: waiting for MODULES Deployments could return before the
# last module's was written, whose pod then never ran (the fleet never Ready)
DEPLOYMENTS = MODULES + 1

Obj = dict[str, Any]


def _docs(path: Path) -> list[Obj]:
    return [d for d in yaml.safe_load_all(path.read_text()) if isinstance(d, dict)]


def _until(what: str, check: Callable[[], Any], seconds: float = 60.0) -> Any:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if out := check():
            return out
        time.sleep(0.1)
    raise AssertionError(f"timed out after {seconds:.0f} s waiting for {what}")


def _condition(obj: Obj | None, type_: str) -> Obj | None:
    for c in ((obj or {}).get("status") or {}).get("conditions") or []:
        if c.get("type") == type_:
            return dict(c)
    return None


@pytest.fixture
def single_robot(api: FakeApi) -> None:
    """The single-robot example (solo-robot, solo-edge, the warehouse's eight modules) with
    its Nodes, Ready as their kubelets would report them, and a small seeded NSGA-II."""
    for node in _docs(ROOT / "e2e" / "bed" / "nodes.yaml"):
        if node["metadata"]["name"] in ("solo-robot", "solo-edge"):
            node["status"]["conditions"] = [{"type": "Ready", "status": "True"}]
            api.create(node)
    api.create({"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": NS}})
    for obj in _docs(EXAMPLES / "single-robot" / "nodes.yaml"):
        api.create(obj)
    for obj in _docs(EXAMPLES / "single-robot" / "modules.yaml"):
        api.create(obj)
    (fleet,) = _docs(EXAMPLES / "single-robot" / "fleet.yaml")
    fleet["spec"]["scheduler"] = {
        "algorithm": "nsga2",
        "seed": 1,
        "population": 16,
        "generations": 4,
    }
    api.create(fleet)


def _operator(api: FakeApi, tmp_path: Path) -> KopfRunner:
    """KopfRunner over the registry ``fogfleet run`` builds; kopf's CLI takes no memo, so a
    first startup handler puts in it what ``operator_main`` would (the runtime, the settings)."""
    kubeconfig = tmp_path / "kubeconfig"
    kubeconfig.write_text(yaml.safe_dump(api.kubeconfig()))
    settings = Settings(
        kubeconfig=str(kubeconfig),
        liveness_port=0,
        metrics_port=0,
        debounce_seconds=0.2,
        workers=2,
        standalone=True,
        leader_election=False,
        prometheus_url=None,
    )

    async def compose(memo: Any, **_: Any) -> None:
        memo.settings = settings
        memo.runtime = build_runtime(settings, serve_metrics=False)

    registry = kopf.OperatorRegistry()
    kopf.on.startup(registry=registry)(compose)
    register(registry, settings)
    return KopfRunner(
        ["run", "--standalone", "--all-namespaces", "--verbose"],
        registry=registry,
        settings=kopf.OperatorSettings(),
        timeout=60,
    )


def _run_pods(api: FakeApi, deployments: list[Obj]) -> None:
    """One Running, Ready pod per Deployment on the node of its affinity; Deployments available."""
    for dep in deployments:
        meta, template = dep["metadata"], dep["spec"]["template"]
        terms = template["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        api.create(
            {
                "apiVersion": "v1",
                "kind": "Pod",
                "metadata": {
                    "name": f"{meta['name']}-0",
                    "namespace": NS,
                    "labels": template["metadata"]["labels"],
                },
                "spec": {"nodeName": terms[0]["matchExpressions"][0]["values"][0]},
                "status": {"phase": "Running", "conditions": [{"type": "Ready", "status": "True"}]},
            }
        )
        api.patch_status(
            "Deployment",
            meta["name"],
            NS,
            {
                "observedGeneration": meta["generation"],
                "replicas": 1,
                "updatedReplicas": 1,
                "readyReplicas": 1,
                "availableReplicas": 1,
            },
        )


@pytest.mark.timeout(180)
@pytest.mark.usefixtures("single_robot")
def test_a_new_fleet_is_planned_applied_and_reported(api: FakeApi, tmp_path: Path) -> None:
    with _operator(api, tmp_path) as runner:
        fleet = _until(
            "the fleet's Scheduled condition",
            lambda: (
                (f := api.get("RobotFleet", "single-robot", NS))
                and (_condition(f, "Scheduled") or {}).get("status") == "True"
                and f
            ),
        )
        deployments = _until(
            "the fleet's Deployments",
            lambda: len(api.list("Deployment", NS)) >= DEPLOYMENTS and api.list("Deployment", NS),
        )
        # the Deployment controller, kube-scheduler and the kubelet: each runs its one pod
        _run_pods(api, deployments)
        ready = _until(
            "the fleet's Ready condition",
            lambda: (
                (f := api.get("RobotFleet", "single-robot", NS))
                and (_condition(f, "Ready") or {}).get("status") == "True"
                and f
            ),
        )

    assert runner.exception is None, runner.output
    assert runner.exit_code == 0, runner.output

    # every Deployment went in by server-side apply, under fogfleet's field manager
    applies = list(api.requests_to("PATCH", containing=f"/apis/apps/v1/namespaces/{NS}/"))
    assert applies and all(r.content_type == "application/apply-patch+yaml" for r in applies)
    assert {r.query.get("fieldManager") for r in applies} == {"fogfleet"}
    assert all(r.query.get("force") == "true" for r in applies)

    # one Deployment per module instance, pinned to the node the plan chose, owned by the fleet
    status = fleet["status"]
    placement = {(p["robot"], p["module"]): p["node"] for p in status["placement"]}
    assert len(placement) == MODULES == status["modulesPlaced"] == status["modulesTotal"]
    assert set(placement.values()) <= {"solo-robot", "solo-edge"}
    assert status["scheduler"] == "nsga2"
    assert status["observedGeneration"] == fleet["metadata"]["generation"]
    pinned = {}
    for dep in deployments:
        owners = dep["metadata"].get("ownerReferences") or []
        assert [(o["kind"], o["name"]) for o in owners] == [("RobotFleet", "single-robot")]
        terms = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        (node,) = terms[0]["matchExpressions"][0]["values"]
        labels = dep["metadata"]["labels"]
        if LABEL_MODULE in labels:  # a module instance (the other: the robot's discovery server)
            pinned[(labels[LABEL_ROBOT], labels[LABEL_MODULE])] = node
    assert pinned == placement

    # the status went through the /status subresource: not Ready while no pod ran, then Ready
    assert (_condition(fleet, "Ready") or {}).get("status") in ("False", "Unknown")
    assert _condition(ready, "Ready")["reason"]
    assert ready["status"]["placement"] == status["placement"]
    status_patches = list(api.requests_to("PATCH", containing="/robotfleets/single-robot/status"))
    assert status_patches
    assert all(r.content_type == "application/merge-patch+json" for r in status_patches)
    # no finalizer: deleting the fleet never waits for the operator
    assert not api.get("RobotFleet", "single-robot", NS)["metadata"].get("finalizers")


def _usage(api: FakeApi) -> dict[str, tuple[list[str], int]]:
    """ComputeNode -> (fleets, instances) as its status says."""
    return {
        cn["metadata"]["name"]: (
            (cn.get("status") or {}).get("fleets") or [],
            (cn.get("status") or {}).get("instances") or 0,
        )
        for cn in api.list("ComputeNode")
    }


@pytest.mark.timeout(180)
@pytest.mark.usefixtures("single_robot")
def test_a_deleted_fleet_leaves_the_compute_nodes_within_one_usage_pass(
    api: FakeApi, tmp_path: Path
) -> None:
    """Issue 36: after its fleet was deleted, edge-4 kept showing 11 instances. The fleet
    has no finalizer, so kopf calls no delete handler; its DELETED event must still forget it
    and run a usage pass (here the fake has no garbage collector, so no Deployment event
    would, and the drift tick is 60 s away)."""
    with _operator(api, tmp_path) as runner:
        deployments = _until(
            "the fleet's Deployments",
            lambda: len(api.list("Deployment", NS)) >= DEPLOYMENTS and api.list("Deployment", NS),
        )
        _run_pods(api, deployments)  # Ready: no re-check of the fleet is pending
        _until(
            "the fleet's Ready condition",
            lambda: (
                (_condition(api.get("RobotFleet", "single-robot", NS), "Ready") or {}).get("status")
                == "True"
            ),
        )
        used = _until(
            "the ComputeNodes' usage of the fleet",
            lambda: sum(n for _, n in _usage(api).values()) == MODULES and _usage(api),
        )
        assert {f for fleets, _ in used.values() for f in fleets} == {f"{NS}/single-robot"}
        t0 = time.monotonic()
        api.delete("RobotFleet", "single-robot", NS)
        _until(
            "the ComputeNodes to drop the deleted fleet",
            lambda: all(u == ([], 0) for u in _usage(api).values()),
            seconds=15,
        )
        took = time.monotonic() - t0
        # the operator deleted its Deployments at once, too (the garbage collector would)
        _until("the fleet's Deployments to go", lambda: not api.list("Deployment", NS), 15)
    assert runner.exception is None, runner.output
    # 15 s tells the DELETED event's own usage pass from the drift tick 60 s away; it holds
    # on a loaded machine (the pass takes well under a second of CPU)
    assert took < 15, took
    modules = api.list("SoftwareModule", NS)
    assert modules and all((m.get("status") or {}).get("instances") == 0 for m in modules)
