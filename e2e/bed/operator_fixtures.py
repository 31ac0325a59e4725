"""Helpers for the operator e2e tests: run `fogfleet run` as a subprocess, load the examples
into a test namespace, read fleet status, pods and events.

The operator is a real process (as in a pod): it can be killed with SIGKILL mid-reconcile and
restarted. Its liveness and metrics endpoints listen on free ports of 127.0.0.1 only.
"""

from __future__ import annotations

import copy
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from e2e.bed.base import BIN_DIR, CACHE_ROOT, KUBECONFIG
from e2e.bed.kube import Kube
from e2e.portable.chart import Helm
from fogfleet.render.wiring import is_ros_object

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "manifests" / "examples"
CRDS = ROOT / "crds"
CHART = ROOT / "charts" / "fogfleet"
OPERATOR_LABELS = "app.kubernetes.io/name=fogfleet,app.kubernetes.io/component=operator"
Obj = dict[str, Any]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Operator:
    """`fogfleet run` against the test cluster, scoped to some namespaces."""

    def __init__(
        self,
        kubeconfig: Path,
        namespaces: list[str],
        log_path: Path,
        env: Mapping[str, str] | None = None,
    ) -> None:
        self.kubeconfig = kubeconfig
        self.namespaces = namespaces
        self.log_path = log_path
        self.extra_env = dict(env or {})
        self.proc: subprocess.Popen[bytes] | None = None
        self.liveness_port = 0
        self.metrics_port = 0
        self.starts = 0

    def start(self) -> Operator:
        self.liveness_port, self.metrics_port = free_port(), free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith("FOGFLEET_")}
        env.update(
            {
                "FOGFLEET_KUBECONFIG": str(self.kubeconfig),
                "KUBECONFIG": str(self.kubeconfig),
                "FOGFLEET_NAMESPACES": ",".join(self.namespaces),
                "FOGFLEET_LIVENESS_PORT": str(self.liveness_port),
                "FOGFLEET_METRICS_PORT": str(self.metrics_port),
                "FOGFLEET_DEBOUNCE_SECONDS": "1",
                "FOGFLEET_DRIFT_INTERVAL_SECONDS": "30",
                "FOGFLEET_LOG_LEVEL": "INFO",
                **self.extra_env,
            }
        )
        log = self.log_path.open("ab")
        log.write(f"\n----- start #{self.starts + 1} -----\n".encode())
        log.flush()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fogfleet", "run"],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            cwd=ROOT,
            start_new_session=True,
        )
        self.starts += 1
        return self

    def wait_live(self, timeout: float = 60) -> None:
        import urllib.request

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc is not None and self.proc.poll() is not None:
                raise AssertionError(
                    f"the operator exited with {self.proc.returncode}:\n{self.logs()}"
                )
            try:
                with urllib.request.urlopen(
                    f"http://127.0.0.1:{self.liveness_port}/healthz", timeout=2
                ):
                    return
            except OSError:
                time.sleep(0.3)
        raise AssertionError(f"the operator was not live after {timeout}s:\n{self.logs()}")

    def metrics(self) -> str:
        import urllib.request

        with urllib.request.urlopen(
            f"http://127.0.0.1:{self.metrics_port}/metrics", timeout=5
        ) as r:
            return str(r.read().decode())

    def kill(self) -> None:
        """SIGKILL: no cleanup, no finalizer handling, like a node crash."""
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()

    def logs(self, lines: int = 80) -> str:
        try:
            rows = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return "(no log)"
        return "\n".join(rows[-lines:])


def example_docs(name: str = "warehouse", namespace: str | None = None) -> list[Obj]:
    """The example's fogfleet objects; namespaced ones moved into ``namespace``."""
    docs: list[Obj] = []
    folder = EXAMPLES / name
    for path in sorted(folder.glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if not isinstance(doc, dict) or doc.get("kind") == "Namespace":
                continue
            doc = copy.deepcopy(doc)
            if namespace and doc["kind"] in ("SoftwareModule", "RobotFleet"):
                doc["metadata"]["namespace"] = namespace
            docs.append(doc)
    return docs


def of_kind(docs: list[Obj], kind: str) -> list[Obj]:
    return [d for d in docs if d["kind"] == kind]


def example_in(name: str, namespace: str) -> list[Obj]:
    """The objects of ``manifests/examples/<name>/`` (its nodes, modules and fleet files) with
    every namespaced one moved to ``namespace``."""
    docs = [
        d
        for f in ("nodes.yaml", "modules.yaml", "fleet.yaml")
        for d in yaml.safe_load_all((EXAMPLES / name / f).read_text())
        if d
    ]
    for d in docs:
        if d["kind"] != "ComputeNode":
            d["metadata"]["namespace"] = namespace
    return docs


def fleet(kube: Kube, namespace: str, name: str = "warehouse") -> Obj:
    out: Obj = kube.kubectl_json("get", "robotfleet", name, "-n", namespace)
    return out


def profiling_of(kube: Kube, namespace: str, module: str) -> Obj:
    """A SoftwareModule's ``status.profiling`` (printed: what the Jobs measured)."""
    obj = kube.kubectl_json("get", "softwaremodule", module, "-n", namespace)
    out: Obj = obj["status"]["profiling"]
    print(f"status.profiling of {module}: {out}")
    return out


def wait_profiling_jobs_deleted(kube: Kube, namespace: str) -> None:
    """The operator deletes a recorded run's profiling Jobs."""
    kube.wait_for(
        "the profiling Jobs deleted",
        lambda: (
            not kube.kubectl_json(
                "get", "jobs", "-n", namespace, "-l", "app.kubernetes.io/component=profiling"
            )["items"]
        ),
        60,
    )


def conditions(obj: Obj) -> dict[str, Obj]:
    return {c["type"]: c for c in (obj.get("status") or {}).get("conditions") or []}


def condition_is(
    kube: Kube,
    namespace: str,
    type_: str,
    status: str,
    name: str = "warehouse",
    reason: str | None = None,
) -> bool:
    try:
        c = conditions(fleet(kube, namespace, name)).get(type_)
    except AssertionError:
        return False
    return bool(c and c["status"] == status and (reason is None or c["reason"] == reason))


def pods_by_instance(kube: Kube, namespace: str) -> dict[str, Obj]:
    """Running, not terminating pods of the fleet, by Deployment (fogfleet.io/instance)."""
    items = kube.kubectl_json(
        "get", "pods", "-n", namespace, "-l", "app.kubernetes.io/managed-by=fogfleet"
    )["items"]
    out: dict[str, Obj] = {}
    for pod in items:
        if pod["metadata"].get("deletionTimestamp") or pod["status"].get("phase") != "Running":
            continue
        instance = pod["metadata"]["labels"].get("fogfleet.io/instance")
        if instance:  # not the robots' discovery servers
            out.setdefault(instance, pod)
    return out


def all_pods(kube: Kube, namespace: str) -> list[Obj]:
    items: list[Obj] = kube.kubectl_json("get", "pods", "-n", namespace)["items"]
    return items


def install_crds(kube: Kube) -> None:
    """Apply crds/ (server-side, ours win) and wait until the API server serves each."""
    kube.kubectl("apply", "--server-side", "--force-conflicts", "-f", str(CRDS))
    for path in sorted(CRDS.glob("*.fogfleet.io.yaml")):
        crd = f"crd/{path.name.removesuffix('.yaml')}"
        kube.kubectl("wait", "--for=condition=Established", crd, "--timeout=60s")


def add_module_to_fleet(kube: Kube, namespace: str, module: str, fleet: str = "warehouse") -> None:
    """Append a module reference to a fleet's spec.modules (a JSON patch, as a user would)."""
    op = [{"op": "add", "path": "/spec/modules/-", "value": {"name": module}}]
    kube.kubectl("patch", "robotfleet", fleet, "-n", namespace, "--type=json", "-p", json.dumps(op))


def deployment_versions(kube: Kube, namespace: str) -> dict[str, str]:
    """Deployment name -> its generation, labels and annotations: equal before and after means
    nothing wrote the Deployment (its status, which kube-controller-manager keeps writing,
    is left out: a resourceVersion would change with it)."""
    return {
        d["metadata"]["name"]: json.dumps(
            [d["metadata"]["generation"], d["metadata"].get("labels"),
             d["metadata"].get("annotations")], sort_keys=True
        )
        for d in deployments(kube, namespace)
    }  # fmt: skip


def deployments(kube: Kube, namespace: str) -> list[Obj]:
    """The modules' Deployments (not the robots' ROS discovery servers)."""
    items: list[Obj] = kube.kubectl_json("get", "deployments", "-n", namespace)["items"]
    return [d for d in items if not is_ros_object(d)]


def bound_node(dep: Obj) -> list[str]:
    values: list[str] = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
        "requiredDuringSchedulingIgnoredDuringExecution"
    ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"]
    return values


def events(
    kube: Kube, namespace: str, reason: str | None = None, name: str = "warehouse"
) -> list[Obj]:
    sel = f"involvedObject.name={name}" + (f",reason={reason}" if reason else "")
    items: list[Obj] = kube.kubectl_json("get", "events", "-n", namespace, "--field-selector", sel)[
        "items"
    ]
    return items


def dump(obj: Any) -> str:
    return json.dumps(obj, indent=1)[:6000]


# --------------------------------------------------------------------------------------------
# the warehouse fleet, as the operator suites use it

N_INSTANCES = 40  # 5 robots x 8 per-robot modules


def apply_warehouse(kube: Kube, namespace: str, **fleet_spec: Any) -> dict[str, Any]:
    docs = example_docs("warehouse", namespace)
    kube.apply(of_kind(docs, "ComputeNode") + of_kind(docs, "SoftwareModule"))
    body = of_kind(docs, "RobotFleet")[0]
    body["spec"].update(fleet_spec)
    kube.apply(body)
    return body


def wait_ready(kube: Kube, namespace: str, name: str = "warehouse", timeout: float = 180) -> None:
    kube.wait_for(
        f"RobotFleet {name} Ready",
        lambda: condition_is(kube, namespace, "Ready", "True", name),
        timeout=timeout,
        interval=1,
    )


def assert_pods_where_planned(
    kube: Kube, namespace: str, name: str = "warehouse", instances: int = N_INSTANCES
) -> dict[str, Any]:
    status = fleet(kube, namespace, name)["status"]
    planned = {(p["robot"], p["module"]): p["node"] for p in status["placement"]}
    assert len(planned) == instances
    pods = pods_by_instance(kube, namespace)
    deps = {
        d["metadata"]["name"]: d
        for d in deployments(kube, namespace)
        if d["metadata"].get("labels", {}).get("fogfleet.io/fleet", name) == name
    }  # the fleet's own: other fleets may share the namespace
    assert len(deps) == instances, sorted(deps)
    for dname, dep in deps.items():
        ann = dep["metadata"]["annotations"]
        want = planned[(ann["fogfleet.io/robot"], ann["fogfleet.io/module"])]
        assert bound_node(dep) == [want]
        assert pods[dname]["spec"]["nodeName"] == want, dname
    return pods


def helm(*args: str, timeout: float = 300) -> str:
    """The bed's helm with the bed's kubeconfig: the portable suite's one wrapper
    (:class:`e2e.portable.chart.Helm`), so its output on failure is the same everywhere."""
    return Helm(str(BIN_DIR / "helm"), KUBECONFIG, CACHE_ROOT / "helm-home")(*args, timeout=timeout)
