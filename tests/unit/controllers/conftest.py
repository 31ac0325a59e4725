"""An in-memory KubePort and a counting planner for controller unit tests."""

from __future__ import annotations

import copy
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.adapters.kube import holds_room, pod_load
from fogfleet.api.labels import LABEL_FLEET
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.decision import CorePlanner
from fogfleet.scheduling.incremental import Replan
from fogfleet.scheduling.schedule import Schedule

ROOT = Path(__file__).resolve().parents[3]
Obj = dict[str, Any]


def docs(*paths: Path) -> list[Obj]:
    out: list[Obj] = []
    for p in paths:
        out += [d for d in yaml.safe_load_all(p.read_text()) if isinstance(d, dict)]
    return out


def _merge(target: Obj, patch: Mapping[str, Any]) -> None:
    """RFC 7386 JSON merge patch, as the API server applies it (None removes a key)."""
    for key, value in patch.items():
        if value is None:
            target.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(target.get(key), dict):
            _merge(target[key], value)
        else:
            target[key] = copy.deepcopy(value)


def _match(labels: Mapping[str, str], selector: Mapping[str, str]) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


class FakeKube:
    def __init__(self) -> None:
        self.fleets: dict[tuple[str, str], Obj] = {}
        self.compute_nodes: dict[str, Obj] = {}
        self.modules: dict[tuple[str, str], Obj] = {}
        self.nodes: dict[str, Obj] = {}
        self.deployments: dict[tuple[str, str], Obj] = {}
        self.services: dict[tuple[str, str], Obj] = {}
        self.network_policies: dict[tuple[str, str], Obj] = {}
        self.pods: dict[tuple[str, str], Obj] = {}
        self.applied: list[str] = []
        self.applied_services: list[str] = []
        self.applied_policies: list[str] = []
        self.deleted: list[str] = []
        self.status_patches: list[Obj] = []
        self.module_patches: list[tuple[str, str]] = []
        self.events: list[tuple[str, str, str]] = []
        self.jobs: dict[tuple[str, str], Obj] = {}
        self.job_pods: dict[tuple[str, str], list[Obj]] = {}  # (ns, job) -> its pods
        self.explanations: list[tuple[str, str, Obj]] = []  # answered requests' status

    # seeding
    def load_warehouse(self) -> None:
        ex = ROOT / "manifests" / "examples" / "warehouse"
        for d in docs(ex / "nodes.yaml", ex / "modules.yaml", ex / "fleet.yaml"):
            self.add(d)
        for d in docs(ROOT / "e2e" / "bed" / "nodes.yaml"):
            d.setdefault("status", {})["conditions"] = [{"type": "Ready", "status": "True"}]
            self.nodes[d["metadata"]["name"]] = d

    def add(self, d: Obj) -> None:
        d = copy.deepcopy(d)
        meta = d["metadata"]
        meta.setdefault("generation", 1)
        meta.setdefault("uid", f"uid-{meta['name']}")
        kind = d["kind"]
        if kind == "ComputeNode":
            self.compute_nodes[meta["name"]] = d
        elif kind == "SoftwareModule":
            self.modules[(meta["namespace"], meta["name"])] = d
        elif kind == "RobotFleet":
            self.fleets[(meta["namespace"], meta["name"])] = d

    def set_ready(self, node: str, ready: bool) -> None:
        self.nodes[node]["status"]["conditions"] = [
            {
                "type": "Ready",
                "status": "True" if ready else "False",
                "reason": "KubeletReady" if ready else "KubeletNotReady",
            }
        ]

    def run_pods(self) -> None:
        """What kube-scheduler + kubelet would do: one Running pod on (the first) affinity node."""
        self.pods.clear()
        for (ns, name), dep in self.deployments.items():
            pod_spec = dep["spec"]["template"]["spec"]
            node = pod_spec["affinity"]["nodeAffinity"][
                "requiredDuringSchedulingIgnoredDuringExecution"
            ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"][0]
            labels = dep["spec"]["template"]["metadata"]["labels"]
            self.pods[(ns, name + "-pod")] = {
                "metadata": {"name": name + "-pod", "namespace": ns, "labels": labels},
                "spec": {"nodeName": node, "containers": pod_spec.get("containers") or []},
                "status": {"phase": "Running", "conditions": [{"type": "Ready", "status": "True"}]},
            }
            dep["status"] = {
                "observedGeneration": dep["metadata"]["generation"],
                "replicas": 1,
                "updatedReplicas": 1,
                "availableReplicas": 1,
            }

    # KubePort
    def get_fleet(self, namespace: str, name: str) -> Obj | None:
        f = self.fleets.get((namespace, name))
        return copy.deepcopy(f) if f else None

    def list_fleets(self, namespace: str | None = None) -> list[Obj]:
        return [copy.deepcopy(f) for (ns, _), f in self.fleets.items() if namespace in (None, ns)]

    def list_compute_nodes(self) -> list[Obj]:
        return copy.deepcopy(list(self.compute_nodes.values()))

    def list_modules(self, namespace: str | None) -> list[Obj]:
        return copy.deepcopy([m for (ns, _), m in self.modules.items() if namespace in (None, ns)])

    def list_nodes(self) -> list[Obj]:
        return copy.deepcopy(list(self.nodes.values()))

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(
            [
                d
                for (ns, _), d in self.deployments.items()
                if ns == namespace and _match(d["metadata"]["labels"], selector)
            ]
        )

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        loads = (pod_load(p) for p in self.pods.values())
        return [p for p in loads if holds_room(p) and not _of(p, besides)]

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(
            [
                p
                for (ns, _), p in self.pods.items()
                if ns == namespace and _match(p["metadata"]["labels"], selector)
            ]
        )

    def apply_deployment(self, body: Obj) -> Obj:
        key = (body["metadata"]["namespace"], body["metadata"]["name"])
        old = self.deployments.get(key)
        new = copy.deepcopy(body)
        new["metadata"]["generation"] = (old["metadata"]["generation"] + 1) if old else 1
        new["status"] = (old or {}).get("status", {})
        self.deployments[key] = new
        self.applied.append(key[1])
        return copy.deepcopy(new)

    def delete_deployment(self, namespace: str, name: str) -> None:
        self.deployments.pop((namespace, name), None)
        self.deleted.append(name)

    def apply_service(self, body: Obj) -> Obj:
        key = (body["metadata"]["namespace"], body["metadata"]["name"])
        new = copy.deepcopy(body)
        old = self.services.get(key)
        # the API server allocates a cluster IP once and keeps it
        ip = old["spec"]["clusterIP"] if old else f"198.19.0.{10 + len(self.services)}"
        new["spec"]["clusterIP"] = ip
        self.services[key] = new
        self.applied_services.append(key[1])
        return copy.deepcopy(new)

    def apply_network_policy(self, body: Obj) -> Obj:
        self.network_policies[(body["metadata"]["namespace"], body["metadata"]["name"])] = body
        self.applied_policies.append(body["metadata"]["name"])
        return copy.deepcopy(body)

    def list_network_policies(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(
            [
                p
                for (ns, _), p in self.network_policies.items()
                if ns == namespace and _match(p["metadata"]["labels"], selector)
            ]
        )

    def delete_network_policy(self, namespace: str, name: str) -> None:
        self.network_policies.pop((namespace, name), None)

    def list_services(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(
            [
                d
                for (ns, _), d in self.services.items()
                if ns == namespace and _match(d["metadata"]["labels"], selector)
            ]
        )

    def delete_service(self, namespace: str, name: str) -> None:
        self.services.pop((namespace, name), None)

    def create_job(self, body: Obj) -> Obj:
        key = (body["metadata"]["namespace"], body["metadata"]["name"])
        self.jobs.setdefault(key, copy.deepcopy(body))
        return copy.deepcopy(self.jobs[key])

    def list_jobs(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(
            [
                j
                for (ns, _), j in self.jobs.items()
                if ns == namespace and _match(j["metadata"]["labels"], selector)
            ]
        )

    def list_job_pods(self, namespace: str, job: str) -> list[Obj]:
        return copy.deepcopy(self.job_pods.get((namespace, job), []))

    def delete_job(self, namespace: str, name: str) -> None:
        self.jobs.pop((namespace, name), None)
        self.job_pods.pop((namespace, name), None)
        self.deleted.append(name)

    def finish_job(self, namespace: str, name: str, message: str, ok: bool = True) -> None:
        """What the Job controller and kubelet would do: the pod ends with ``message``."""
        job = self.jobs[(namespace, name)]
        job["status"] = {"succeeded": 1} if ok else {
            "failed": 1,
            "conditions": [{"type": "Failed", "status": "True", "reason": "BackoffLimitExceeded",
                            "message": "Job has reached the specified backoff limit"}],
        }  # fmt: skip
        state = {"exitCode": 0 if ok else 2, "reason": "Completed" if ok else "Error",
                 "message": message}  # fmt: skip
        self.job_pods[(namespace, name)] = [
            {
                "metadata": {"name": f"{name}-x", "namespace": namespace},
                "spec": {"nodeName": "somewhere"},
                "status": {
                    "phase": "Succeeded" if ok else "Failed",
                    "containerStatuses": [{"name": "m", "state": {"terminated": state}}],
                },
            }
        ]

    def patch_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        _merge(self.fleets[(namespace, name)].setdefault("status", {}), status)
        self.status_patches.append(copy.deepcopy(dict(status)))

    def patch_explanation_status(
        self, namespace: str, name: str, status: Mapping[str, Any]
    ) -> None:
        self.explanations.append((namespace, name, dict(status)))

    def delete_explanation_request(self, namespace: str, name: str) -> None:
        self.deleted.append(f"ExplanationRequest/{namespace}/{name}")

    def list_deployment_metadata(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self.list_deployments(namespace, selector)

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        _merge(self.modules[(namespace, name)].setdefault("status", {}), status)
        self.module_patches.append((namespace, name))

    def patch_compute_node_status(self, name: str, status: Mapping[str, Any]) -> None:
        _merge(self.compute_nodes[name].setdefault("status", {}), status)
        self.status_patches.append({"computenode": name, **copy.deepcopy(dict(status))})

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None:
        module = self.modules[(namespace, name)]
        module.setdefault("metadata", {}).setdefault("annotations", {}).update(annotations)

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None:
        self.events.append((type_, reason, message))


class CountingPlanner:
    """The real planner (NSGA-II and the references, as the operator runs it) on a small
    budget with a generation limit instead of a clock, so plans are reproducible; counts
    whole-fleet plans (``calls``) and incremental re-plans that returned a plan
    (``replans``)."""

    def __init__(self) -> None:
        self.calls = 0
        self.replans = 0

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule:
        self.calls += 1
        small = {"population": 16, "generations": 4, "time_budget_millis": 60_000}
        return CorePlanner().plan(problem, settings.model_copy(update=small))

    def replan(
        self,
        problem: Problem,
        settings: SchedulerSettings,
        changed: Collection[int],
        reference: float | None,
    ) -> Replan:
        out = CorePlanner().replan(problem, settings, changed, reference)
        self.replans += out.schedule is not None
        return out


@pytest.fixture
def merge_patch() -> Any:
    """RFC 7386 JSON merge patch (target, patch), as the API server applies it."""
    return _merge


@pytest.fixture
def kube() -> FakeKube:
    k = FakeKube()
    k.load_warehouse()
    return k


@pytest.fixture
def make_deps(kube: FakeKube) -> Any:
    from fogfleet.controllers.deps import Deps

    return lambda: Deps(kube=kube, planner=CountingPlanner())


@pytest.fixture
def deps(make_deps: Any) -> Any:
    return make_deps()


def _of(load: Obj, fleet: tuple[str, str] | None) -> bool:
    """A Pod of ``fleet`` (namespace, fleet label value), which the API server leaves out of
    a list with ``besides`` (``KubeClient.list_node_load``)."""
    if fleet is None:
        return False
    meta = load.get("metadata") or {}
    return (meta.get("namespace"), (meta.get("labels") or {}).get(LABEL_FLEET)) == fleet
