"""Operator benchmarks of issue 4 on the local control plane, printed as one table.

    .venv/bin/python e2e/bench/cluster.py [--runs 5] [--robots 50] [--json] [--skip-large]

1. **Apply-to-all-Running latency** (median/min/max of ``--runs``) for the warehouse fleet
   (5 robots x 8 modules = 40 pods) and a ``--robots`` fleet (8 pods per robot), two paths:

   * ``operator``: ``kubectl apply --server-side`` of the RobotFleet (its SoftwareModules and
     ComputeNodes exist already) -> kopf -> NSGA-II plan -> server-side applied Deployments with
     a required node affinity -> kube-scheduler -> kwok -> every pod Running;
   * ``plain``: the same pods as plain Deployments (``render_fleet(..., baseline=True)``: the
     taxonomy's allowed node set as affinity, nominal requests) and the robots' ROS 2 discovery
     servers the operator also runs (``plain_discovery``; since 2026-11-27) applied with one
     ``kubectl apply --server-side``; kube-scheduler alone decides.

   The clock starts just before ``kubectl apply`` and stops when a pod watch (started before the
   apply) has seen every expected pod Running. The planning time is the fleet's
   ``status.planningMillis``. Target (issue 4): operator <= 1.5 x plain + planning, reported as
   ``(operator - planning) / plain``. Runs alternate operator/plain, each in a fresh namespace
   that is deleted afterwards (waiting until its pods are gone).

2. **Missed-cycle rate** of the operator's nsga2 plan vs kube-scheduler's real placement of the
   same fleet: a ``scheduler: k8s-default`` fleet runs through the operator, its
   ``status.placement`` (kube-scheduler's bindings) is read back, and both plans are simulated
   with ``fogfleet.sim.simulate`` (same seeds; ``all_active=True``, the paper's IV-B setting,
   and the Table II activation rates). Target: >= 90 % fewer misses.

Cluster sharing: the control plane may be shared with other e2e runs. Nothing is restarted and
the node set is not replaced: the benchmark ADDS its own Nodes (``bench-wh-*`` for the warehouse
copy, ``bench-robot-*``/``bench-edge-*`` for the large fleet; kwok manages every Node) and
ComputeNodes, all labelled ``fogfleet.io/bench=true``, runs its own ``fogfleet run`` scoped to
its own namespaces, and deletes all of it at the end (also after a failure or Ctrl-C).
Everything talks to 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import secrets
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT, ROOT / "operator"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import numpy as np  # noqa: E402

from e2e.bed import harness  # noqa: E402
from e2e.bed.cpu_meter import CpuMeter  # noqa: E402
from e2e.bed.fakenodes import only_simulated_taint  # noqa: E402
from e2e.bed.kube import Kube, guard_kubeconfig  # noqa: E402
from e2e.bed.operator_fixtures import (  # noqa: E402
    Operator,
    example_docs,
    install_crds,
    of_kind,
)
from fogfleet.api.labels import LABEL_COMPONENT  # noqa: E402
from fogfleet.render.ros import COMPONENT_DISCOVERY  # noqa: E402

Obj = dict[str, Any]
BENCH_LABEL = "fogfleet.io/bench"
MODULES_PER_ROBOT = 8
WAREHOUSE_EDGES = 6


def log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def loadavg() -> str:
    return "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


# --------------------------------------------------------------------------------------------
# fleets: the warehouse copy and the large synthetic fleet, on the benchmark's own nodes


class FleetSpec:
    """The objects of one benchmark fleet (namespace-free; placed into a namespace per run)."""

    def __init__(
        self, key: str, fleet_name: str, compute_nodes: list[Obj], modules: list[Obj], fleet: Obj
    ):
        self.key = key
        self.fleet_name = fleet_name
        self.compute_nodes = compute_nodes
        self.modules = modules
        self.fleet = fleet
        self.pods = len(fleet["spec"]["robots"]) * len(fleet["spec"]["modules"])

    def k8s_nodes(self) -> list[Obj]:
        out = []
        for cn in self.compute_nodes:
            spec = cn["spec"]
            cap = spec["capacity"]
            mem = str(cap["memory"])
            node = harness.node_object(
                cn["metadata"]["name"],
                spec["tier"],
                spec["hardwareType"],
                int(cap["cpu"]),
                int(mem.removesuffix("Gi")),
                robot=cn["metadata"]["name"] if spec["tier"] == "robot" else None,
            )
            node["metadata"]["labels"][BENCH_LABEL] = "true"
            out.append(node)
        return out

    def modules_in(self, ns: str) -> list[Obj]:
        out = []
        for m in self.modules:
            m = copy.deepcopy(m)
            m["metadata"] = {"name": m["metadata"]["name"], "namespace": ns}
            out.append(m)
        return out

    def fleet_in(self, ns: str, algorithm: str = "nsga2") -> Obj:
        f = copy.deepcopy(self.fleet)
        f["metadata"] = {"name": self.fleet_name, "namespace": ns}
        f["spec"]["scheduler"] = {**f["spec"].get("scheduler", {}), "algorithm": algorithm}
        return f

    def catalog(self, ns: str) -> Any:
        from fogfleet.api.loader import Catalog, parse_object

        cat = Catalog()
        for doc in [*self.compute_nodes, *self.modules_in(ns), self.fleet_in(ns)]:
            cat.add(parse_object(doc))
        return cat

    def problem(self, ns: str) -> Any:
        from fogfleet.domain.build import build_problem

        cat = self.catalog(ns)
        return build_problem(cat.fleets[0], cat), cat


def _bench_cn(doc: Obj, name: str) -> Obj:
    doc = copy.deepcopy(doc)
    doc["metadata"] = {"name": name, "labels": {BENCH_LABEL: "true"}}
    doc.pop("status", None)
    return doc


def warehouse_spec() -> FleetSpec:
    docs = example_docs("warehouse")
    rename: dict[str, str] = {}
    nodes = []
    for cn in of_kind(docs, "ComputeNode"):
        old = cn["metadata"]["name"]
        rename[old] = f"bench-wh-{old}"
        nodes.append(_bench_cn(cn, rename[old]))
    fleet = of_kind(docs, "RobotFleet")[0]
    fleet["spec"]["robots"] = [rename[r] for r in fleet["spec"]["robots"]]
    fleet["spec"]["nodes"] = [rename[n] for n in fleet["spec"]["nodes"]]
    used = set(fleet["spec"]["robots"]) | set(fleet["spec"]["nodes"])
    nodes = [n for n in nodes if n["metadata"]["name"] in used]  # no cloud/solo nodes
    return FleetSpec("warehouse", "warehouse", nodes, of_kind(docs, "SoftwareModule"), fleet)


def large_spec(robots: int, edges: int, seed: int = 1) -> FleetSpec:
    """``synthetic_fleet`` (warehouse robots, 12 edge cores per robot on average) renamed to
    bench-robot-k / bench-edge-k."""
    from fogfleet.bench.scheduling import synthetic_fleet

    cat, fl = synthetic_fleet(robots, edges, seed)
    rename = {r: f"bench-robot-{k + 1}" for k, r in enumerate(fl.spec.robots)}
    rename |= {e: f"bench-edge-{k + 1}" for k, e in enumerate(fl.spec.nodes)}
    nodes = [
        _bench_cn(cat.nodes[old].model_dump(by_alias=True, exclude_none=True, mode="json"), new)
        for old, new in rename.items()
    ]
    docs = example_docs("warehouse")
    fleet = of_kind(docs, "RobotFleet")[0]
    fleet["spec"]["robots"] = [rename[r] for r in fl.spec.robots]
    fleet["spec"]["nodes"] = [rename[e] for e in fl.spec.nodes]
    return FleetSpec(
        f"{robots}-robot", f"fleet{robots}", nodes, of_kind(docs, "SoftwareModule"), fleet
    )


# --------------------------------------------------------------------------------------------
# cluster access and watches


def connect(profile: str | None = None) -> Kube:
    """The running bed, started if none runs; with ``profile``, a bed of that profile (one of
    another profile is restarted as it)."""
    cluster = harness.running()
    if cluster is None or (profile is not None and cluster.profile != profile):
        log(f"starting the local bed ({profile or 'default'} profile; harness ensure_up)")
        cluster = harness.ensure_up(**({"profile": profile} if profile else {}))
    server = guard_kubeconfig(cluster.kubeconfig, expected_server=cluster.api_server)
    return Kube(
        kubeconfig=cluster.kubeconfig,
        server=server,
        kubectl_bin=str(harness.BIN_DIR / "kubectl"),
        external=False,
        cluster=cluster,
    )


# The fleet's modules, not the ROS discovery servers the operator adds per robot (a plain
# fleet has none): counting those made "all Running" fire while up to one module pod per robot
# was still to come.
MODULES_ONLY = f"{LABEL_COMPONENT}!={COMPONENT_DISCOVERY}"
PLAIN_MANAGER = "fogfleet-bench-plain"


class Watcher:
    """Watches a namespace's module pods and Deployments (``MODULES_ONLY``) from before the
    apply; records when the first/last Deployment appeared and when ``expected`` pods were
    Running at once."""

    def __init__(self, kube: Kube, ns: str, expected: int) -> None:
        from kubernetes import client

        self.api = kube.api_client()
        self.core = client.CoreV1Api(self.api)
        self.apps = client.AppsV1Api(self.api)
        self.ns = ns
        self.expected = expected
        self.running: set[str] = set()
        self.deployments: set[str] = set()
        self.first_dep: float | None = None
        self.last_dep: float | None = None
        self.all_running: float | None = None
        self.done = threading.Event()
        self.error: BaseException | None = None
        self._stop = False
        only = {"label_selector": MODULES_ONLY}
        rv_pods = str(self.core.list_namespaced_pod(ns, **only).metadata.resource_version)  # type: ignore[union-attr]
        rv_deps = str(self.apps.list_namespaced_deployment(ns, **only).metadata.resource_version)  # type: ignore[union-attr]
        self._threads = [
            threading.Thread(target=self._guard(self._pods, rv_pods), daemon=True),
            threading.Thread(target=self._guard(self._deps, rv_deps), daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _guard(self, fn: Callable[[str], None], rv: str) -> Callable[[], None]:
        def run() -> None:
            try:
                fn(rv)
            except BaseException as exc:  # reported by wait()
                if not self._stop:
                    self.error = exc
                    self.done.set()

        return run

    def _stream(self, list_fn: Any, rv: str) -> Any:
        """(type, object as a dict) events; after a watch ERROR (e.g. 410 Gone) it re-lists
        and yields ("RELIST", None) followed by every listed object as "ADDED".

        Objects stay JSON dicts: the client's typed models cost milliseconds per Pod, and at
        8000 pods on this machine the watch fell 15 s behind the cluster it was timing."""
        from kubernetes import watch
        from kubernetes.client.exceptions import ApiException

        def raw(*args: Any, **kwargs: Any) -> Any:  # no return annotation: dicts, not models
            return list_fn(*args, **kwargs)

        while not self._stop:
            w: Any = watch.Watch()  # type: ignore[no-untyped-call]
            relist = False
            try:
                for ev in w.stream(
                    raw,
                    self.ns,
                    resource_version=rv,
                    timeout_seconds=60,
                    allow_watch_bookmarks=True,
                    label_selector=MODULES_ONLY,
                ):
                    obj = ev["raw_object"]
                    rv = (obj.get("metadata") or {}).get("resourceVersion") or rv
                    if ev["type"] == "BOOKMARK":
                        continue
                    yield ev["type"], obj
                    if self._stop:
                        w.stop()
                        return
            except ApiException as exc:  # the client raises a watch's ERROR event
                if exc.status != 410:
                    raise
                relist = True  # 410 Gone: our resourceVersion is too old
            if relist and not self._stop:
                resp = list_fn(self.ns, label_selector=MODULES_ONLY, _preload_content=False)
                listed = json.loads(resp.data)
                rv = str(listed["metadata"]["resourceVersion"])
                yield "RELIST", None
                for item in listed.get("items") or []:
                    yield "ADDED", item

    def _pods(self, rv: str) -> None:
        for kind, pod in self._stream(self.core.list_namespaced_pod, rv):
            if kind == "RELIST":
                self.running.clear()
                continue
            meta = pod.get("metadata") or {}
            ok = (
                kind != "DELETED"
                and not meta.get("deletionTimestamp")
                and (pod.get("status") or {}).get("phase") == "Running"
            )
            if ok:
                self.running.add(meta["name"])
            else:
                self.running.discard(meta["name"])
            if self.all_running is None and len(self.running) >= self.expected:
                self.all_running = time.monotonic()
                self.done.set()
                return

    def _deps(self, rv: str) -> None:
        for kind, dep in self._stream(self.apps.list_namespaced_deployment, rv):
            if kind != "ADDED" or dep is None or dep["metadata"]["name"] in self.deployments:
                continue
            t = time.monotonic()
            self.deployments.add(dep["metadata"]["name"])
            self.first_dep = self.first_dep or t
            self.last_dep = t
            if len(self.deployments) >= self.expected:
                return

    def wait(self, timeout: float) -> None:
        if not self.done.wait(timeout):
            self.close()
            raise TimeoutError(
                f"{self.ns}: {len(self.running)} of {self.expected} pods Running after {timeout}s"
            )
        if self.error is not None:
            self.close()
            raise RuntimeError(f"watch of {self.ns} failed: {self.error!r}")
        deadline = time.monotonic() + 10  # the Deployment watch is at most a moment behind
        while len(self.deployments) < self.expected and time.monotonic() < deadline:
            time.sleep(0.05)

    def close(self) -> None:
        self._stop = True
        self.api.close()


def create_namespace(kube: Kube, ns: str) -> None:
    """A benchmark's namespace (labelled as one)."""
    kube.create_namespace(ns, {BENCH_LABEL: "true"})


def delete_namespace(kube: Kube, ns: str, timeout: float = 600) -> float:
    """Delete the namespace and wait until it (and so every pod in it) is gone; seconds taken."""
    t0 = time.monotonic()
    kube.kubectl(
        "delete", "robotfleets", "--all", "-n", ns, "--wait=false", check=False, timeout=60
    )
    kube.kubectl("delete", "namespace", ns, "--ignore-not-found", "--wait=false", check=False)
    kube.wait_for(
        f"namespace {ns} gone",
        lambda: kube.kubectl("get", "namespace", ns, check=False).returncode != 0,
        timeout=timeout,
        interval=1,
    )
    return time.monotonic() - t0


def server_side_apply(kube: Kube, objs: list[Obj], manager: str, timeout: float = 600) -> None:
    manifest = json.dumps({"apiVersion": "v1", "kind": "List", "items": objs})
    kube.kubectl(
        "apply", "--server-side", f"--field-manager={manager}", "-f", "-",
        input=manifest, timeout=timeout,
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# one measured run


def run_operator(kube: Kube, spec: FleetSpec, ns: str, algorithm: str, timeout: float) -> Obj:
    """Apply the fleet in ``ns`` (served by our operator); time until every pod Running."""
    create_namespace(kube, ns)
    server_side_apply(kube, spec.modules_in(ns), "fogfleet-bench")
    watcher = Watcher(kube, ns, spec.pods)
    try:
        t0 = time.monotonic()
        server_side_apply(kube, [spec.fleet_in(ns, algorithm)], "fogfleet-bench")
        t_applied = time.monotonic()
        watcher.wait(timeout)
    finally:
        watcher.close()
    assert watcher.all_running is not None
    # status: planningMillis is written with the Deployments; placement follows the rollout
    status: Obj = {}
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        fleet = kube.kubectl_json("get", "robotfleet", spec.fleet_name, "-n", ns)
        status = fleet.get("status") or {}
        conds = {c["type"]: c["status"] for c in status.get("conditions") or []}
        if conds.get("Ready") == "True" and len(status.get("placement") or []) == spec.pods:
            break
        time.sleep(0.5)
    t_ready = time.monotonic()
    return {
        "total_s": watcher.all_running - t0,
        "kubectl_s": t_applied - t0,
        "first_deployment_s": (watcher.first_dep or np.nan) - t0,
        "last_deployment_s": (watcher.last_dep or np.nan) - t0,
        "ready_condition_s": t_ready - t0,
        "planning_s": (status.get("planningMillis") or 0) / 1000.0,
        "placement": status.get("placement") or [],
        "status": status,
    }


def plain_discovery(problem: Any, fleet: Any) -> list[Obj]:
    """The robots' Fast DDS discovery servers (a Service and a Deployment each) as the
    operator runs them for ``fleet`` (none with ``spec.ros.enabled: false``): a plain ROS 2
    fleet whose modules span nodes needs them too, so the plain baseline runs the same pods."""
    from fogfleet.api.labels import LABEL_FLEET, LABEL_MANAGED_BY
    from fogfleet.render.deployments import label_value
    from fogfleet.render.ros import discovery_servers

    if not fleet.spec.ros.enabled:
        return []
    labels = {LABEL_FLEET: label_value(problem.fleet), LABEL_MANAGED_BY: PLAIN_MANAGER}
    servers = discovery_servers(problem, fleet.spec.ros, labels, [])
    return [doc for _, service, deployment in servers for doc in (service, deployment)]


def run_plain(
    kube: Kube, spec: FleetSpec, ns: str, timeout: float, meter: CpuMeter | None = None
) -> Obj:
    """The same pods as plain Deployments (k8s-default rendering) and the robots' discovery
    servers, kube-scheduler alone; timed to the module pods, as the operator's fleet is
    (``meter``: started at the apply, stopped when the last pod runs)."""
    from fogfleet.render.deployments import render_fleet

    create_namespace(kube, ns)
    problem, cat = spec.problem(ns)
    modules = {name: m for (_, name), m in cat.modules.items()}
    deps = render_fleet(problem, modules, None, baseline=True)
    assert len(deps) == spec.pods, len(deps)
    servers = plain_discovery(problem, cat.fleets[0])
    # the servers first, as the operator writes them (controllers/fleet/apply.py)
    docs = [*servers, *deps]
    watcher = Watcher(kube, ns, spec.pods)
    try:
        if meter is not None:
            meter.start()
        t0 = time.monotonic()
        server_side_apply(kube, docs, PLAIN_MANAGER, timeout=timeout)
        t_applied = time.monotonic()
        watcher.wait(timeout)
        if meter is not None:
            meter.stop()
    finally:
        watcher.close()
    assert watcher.all_running is not None
    return {
        "total_s": watcher.all_running - t0,
        "kubectl_s": t_applied - t0,
        "discovery_servers": sum(d["kind"] == "Deployment" for d in servers),
        "first_deployment_s": (watcher.first_dep or np.nan) - t0,
        "last_deployment_s": (watcher.last_dep or np.nan) - t0,
    }


# --------------------------------------------------------------------------------------------
# missed cycles: the operator's nsga2 plan vs kube-scheduler's real placement


def placement_array(problem: Any, placement: Sequence[Obj]) -> np.ndarray:
    index = {(inst.robot, inst.module): i for i, inst in enumerate(problem.instances)}
    x = np.full(problem.n_instances, -1, dtype=np.int64)
    for entry in placement:
        x[index[(entry["robot"], entry["module"])]] = problem.node_index(entry["node"])
    missing = [problem.label(i) for i in np.flatnonzero(x < 0)]
    if missing:
        raise RuntimeError(f"placement misses {len(missing)} instances: {missing[:5]}")
    return x


def miss_rates(
    problem: Any,
    nsga2: np.ndarray,
    k8s: np.ndarray,
    seeds: Sequence[int],
    duration_s: float,
) -> list[Obj]:
    from fogfleet.sim import simulate

    rows = []
    for all_active in (True, False):
        ours = [
            simulate(problem, nsga2, problem.limits, duration_s, s, all_active=all_active).miss_rate
            for s in seeds
        ]
        base = [
            simulate(problem, k8s, problem.nominal, duration_s, s, all_active=all_active).miss_rate
            for s in seeds
        ]
        m_ours, m_base = statistics.median(ours), statistics.median(base)
        reduction = 1.0 - m_ours / m_base if m_base > 0 else float("nan")
        rows.append(
            {
                "fleet": problem.fleet,
                "activity": "all-active (IV-B)" if all_active else "Table II rates",
                "seeds": len(seeds),
                "duration_s": duration_s,
                "k8s_real_median": m_base,
                "k8s_real_min": min(base),
                "k8s_real_max": max(base),
                "nsga2_median": m_ours,
                "nsga2_min": min(ours),
                "nsga2_max": max(ours),
                "reduction": reduction,
                "target_met": bool(reduction >= 0.9),
            }
        )
    return rows


# --------------------------------------------------------------------------------------------
# the benchmark


def stats(values: Sequence[float]) -> Obj:
    v = [float(x) for x in values if x == x]
    if not v:
        return {"median": float("nan"), "min": float("nan"), "max": float("nan"), "n": 0}
    return {"median": statistics.median(v), "min": min(v), "max": max(v), "n": len(v)}


def setup_cluster(kube: Kube, specs: Sequence[FleetSpec]) -> None:
    install_crds(kube)
    nodes = [n for s in specs for n in s.k8s_nodes()]
    cns = [c for s in specs for c in s.compute_nodes]
    log(f"adding {len(nodes)} bench Nodes and ComputeNodes")
    kube.apply(nodes)
    server_side_apply(kube, cns, "fogfleet-bench")
    names = {n["metadata"]["name"] for n in nodes}

    def ready() -> bool:
        items = kube.kubectl_json("get", "nodes", "-l", f"{BENCH_LABEL}=true")["items"]
        ok = {
            n["metadata"]["name"]
            for n in items
            if any(
                c["type"] == "Ready" and c["status"] == "True"
                for c in n.get("status", {}).get("conditions", [])
            )
            and only_simulated_taint(n)
        }
        return names <= ok

    kube.wait_for(f"{len(names)} bench nodes Ready and untainted", ready, timeout=180, interval=1)


def drop_fleet_finalizers(kube: Kube, ns: str) -> None:
    """Safety net when no operator runs any more: a deleted fleet would keep its namespace."""
    out = kube.kubectl("get", "robotfleets", "-n", ns, "-o", "name", check=False).stdout.split()
    for name in out:
        kube.kubectl(
            "patch", name, "-n", ns, "--type=merge", "-p", '{"metadata":{"finalizers":[]}}',
            check=False,
        )  # fmt: skip


def teardown_cluster(kube: Kube, namespaces: Sequence[str], operator_running: bool = True) -> None:
    for ns in namespaces:
        if kube.kubectl("get", "namespace", ns, check=False).returncode == 0:
            if not operator_running:
                drop_fleet_finalizers(kube, ns)
            try:
                delete_namespace(kube, ns, timeout=180)
            except AssertionError as exc:
                log(f"cleanup: {exc}; removing fleet finalizers")
                drop_fleet_finalizers(kube, ns)
                try:
                    delete_namespace(kube, ns, timeout=120)
                except AssertionError as exc2:
                    log(f"cleanup: {exc2}")
    sel = f"{BENCH_LABEL}=true"
    for kind in ("computenodes", "nodes"):
        # kubectl deletes one object per request: 1400 of them outlast a short --wait on a
        # loaded API server, and a cleanup that raises would lose the measured row
        try:
            kube.kubectl("delete", kind, "-l", sel, "--wait=false", check=False, timeout=900)
            kube.wait_for(
                f"bench {kind} gone",
                lambda kind=kind: (
                    not kube.kubectl(
                        "get", kind, "-l", sel, "-o", "name", check=False, timeout=120
                    ).stdout.strip()
                ),
                timeout=900,
                interval=5,
            )
        except (AssertionError, subprocess.TimeoutExpired) as exc:
            log(f"cleanup: {kind}: {exc}")
    log("removed the bench namespaces, ComputeNodes and Nodes")


def leftover_namespaces(kube: Kube) -> list[str]:
    out = kube.kubectl_json("get", "namespaces", "-l", f"{BENCH_LABEL}=true")["items"]
    return [n["metadata"]["name"] for n in out]


def bench(args: argparse.Namespace) -> Obj:
    kube = connect()
    specs = [warehouse_spec()]
    if not args.skip_large:
        specs.append(large_spec(args.robots, args.edges))
    token = secrets.token_hex(2)
    plan_ns = {
        (s.key, k): f"bench-{token}-op-{s.fleet_name}-{k}"
        for s in specs
        for k in range(max(args.runs, args.large_runs))
    }
    k8s_ns = {s.key: f"bench-{token}-op-{s.fleet_name}-k8s" for s in specs}
    plain_ns = {
        (s.key, k): f"bench-{token}-plain-{s.fleet_name}-{k}"
        for s in specs
        for k in range(max(args.runs, args.large_runs))
    }
    op_namespaces = [*plan_ns.values(), *k8s_ns.values()]
    report: Obj = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "load_before": loadavg(),
        "cpus": os.cpu_count(),
        "latency": [],
        "runs": [],
        "missed_cycles": [],
    }
    stale = leftover_namespaces(kube)
    if stale:
        log(f"removing {len(stale)} namespaces left by an earlier benchmark: {stale}")
        teardown_cluster(kube, stale, operator_running=False)
    logdir = Path(tempfile.mkdtemp(prefix="fogfleet-bench-"))
    op = Operator(kube.kubeconfig, op_namespaces, logdir / "operator.log")
    try:
        setup_cluster(kube, specs)
        op.start().wait_live()
        log(f"operator pid {op.proc.pid if op.proc else '?'}; log {op.log_path}")
        for spec in specs:
            runs = args.runs if spec.pods <= 40 else args.large_runs
            try:
                measure_fleet(kube, spec, args, runs, plan_ns, plain_ns, k8s_ns[spec.key], report)
            except Exception as exc:  # keep what was measured; report the failure
                log(f"{spec.key}: FAILED: {exc!r}")
                report.setdefault("errors", []).append(f"{spec.key}: {exc!r}")
    finally:
        # namespaces first, while the operator still runs (it removes its fleet finalizer)
        teardown_cluster(kube, [*op_namespaces, *plain_ns.values()])
        op.stop()
        report["operator_log"] = str(op.log_path)
    report["load_after"] = loadavg()
    return report


def measure_fleet(
    kube: Kube,
    spec: FleetSpec,
    args: argparse.Namespace,
    runs: int,
    plan_ns: dict[tuple[str, int], str],
    plain_ns: dict[tuple[str, int], str],
    k8s_ns: str,
    report: Obj,
) -> None:
    timeout = args.timeout if spec.pods <= 40 else args.timeout * 4
    per: dict[str, list[Obj]] = {"operator": [], "plain": []}
    last_plan: list[Obj] = []
    try:
        for k in range(runs):
            for path in ("operator", "plain"):  # alternate, so both see the same noise
                ns = plan_ns[(spec.key, k)] if path == "operator" else plain_ns[(spec.key, k)]
                load = os.getloadavg()[0]
                if path == "operator":
                    r = run_operator(kube, spec, ns, "nsga2", timeout)
                    last_plan = r.pop("placement")
                    r.pop("status")
                else:
                    r = run_plain(kube, spec, ns, timeout)
                r["cleanup_s"] = delete_namespace(kube, ns)
                r.update({"fleet": spec.key, "path": path, "run": k + 1, "load1": load})
                per[path].append(r)
                report["runs"].append(r)
                log(
                    f"{spec.key} {path} run {k + 1}: all Running after {r['total_s']:.1f}s"
                    + (f" (planning {r['planning_s']:.1f}s)" if path == "operator" else "")
                    + f"; cleanup {r['cleanup_s']:.1f}s; load1 {load:.2f}"
                )
    finally:
        if per["operator"] and per["plain"]:
            report["latency"].append(latency_summary(spec, per))
    if not args.skip_misses and last_plan:
        report["missed_cycles"] += missed_cycles(kube, spec, k8s_ns, last_plan, args, timeout)


def latency_summary(spec: FleetSpec, per: dict[str, list[Obj]]) -> Obj:
    op, plain = per["operator"], per["plain"]
    s: Obj = {"fleet": spec.key, "pods": spec.pods, "runs": len(op)}
    for key in ("total_s", "kubectl_s", "first_deployment_s", "last_deployment_s", "cleanup_s"):
        s[f"plain_{key}"] = stats([r[key] for r in plain])
        s[f"operator_{key}"] = stats([r[key] for r in op])
    s["operator_planning_s"] = stats([r["planning_s"] for r in op])
    s["operator_ready_condition_s"] = stats([r["ready_condition_s"] for r in op])
    s["operator_minus_planning_s"] = stats([r["total_s"] - r["planning_s"] for r in op])
    s["load1"] = stats([r["load1"] for r in [*op, *plain]])
    med_plain = s["plain_total_s"]["median"]
    ratio = s["operator_minus_planning_s"]["median"] / med_plain
    s["ratio_operator_minus_planning_to_plain"] = ratio
    s["target_s"] = 1.5 * med_plain + s["operator_planning_s"]["median"]
    s["target_met"] = bool(s["operator_total_s"]["median"] <= s["target_s"])
    return s


def missed_cycles(
    kube: Kube, spec: FleetSpec, ns: str, nsga2_placement: list[Obj], args: argparse.Namespace,
    timeout: float,
) -> list[Obj]:  # fmt: skip
    log(f"{spec.key}: k8s-default fleet through the operator for kube-scheduler's placement")
    r = run_operator(kube, spec, ns, "k8s-default", timeout)
    real = r["placement"]
    sched = r["status"].get("scheduler")
    delete_namespace(kube, ns)
    if sched != "k8s-default" or len(real) != spec.pods:
        raise RuntimeError(f"k8s-default fleet recorded {len(real)} placements ({sched})")
    problem, _ = spec.problem(ns)
    x_k8s = placement_array(problem, real)
    x_ours = placement_array(problem, nsga2_placement)
    small = spec.pods <= 40
    seeds = list(range(1, (args.seeds if small else args.large_seeds) + 1))
    duration = args.sim_seconds if small else args.large_sim_seconds
    log(f"{spec.key}: simulating both plans, {len(seeds)} seeds x {duration:.0f}s x 2 modes")
    t0 = time.monotonic()
    rows = miss_rates(problem, x_ours, x_k8s, seeds, duration)

    def tiers(x: np.ndarray) -> str:
        return "/".join(
            str(sum(problem.nodes[j].tier.value == t for j in x))
            for t in ("robot", "edge", "cloud")
        )

    for row in rows:
        row["fleet"] = spec.key
        row["split_nsga2"] = tiers(x_ours)
        row["split_k8s_real"] = tiers(x_k8s)
        row["k8s_operator_total_s"] = r["total_s"]
    log(f"{spec.key}: simulation took {time.monotonic() - t0:.0f}s")
    return rows


# --------------------------------------------------------------------------------------------
# output


def fmt_s(st: Obj) -> list[str]:
    return [f"{st['median']:.2f}", f"{st['min']:.2f}", f"{st['max']:.2f}"]


def table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(r: list[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def format_report(rep: Obj) -> str:
    out = [
        f"fogfleet operator benchmarks  ({rep['command']})",
        f"{rep['cpus']} CPUs; load average (1/5/15 min) before: {rep['load_before']}, "
        f"after: {rep.get('load_after', '?')}",
        "",
        "== apply-to-all-Running latency, seconds (median / min / max over runs)",
    ]
    rows = []
    for s in rep["latency"]:
        f = f"{s['fleet']} ({s['pods']} pods, n={s['runs']})"
        rows += [
            [f, "plain Deployments: all Running", *fmt_s(s["plain_total_s"])],
            ["", "plain: kubectl apply returned", *fmt_s(s["plain_kubectl_s"])],
            ["", "operator: all Running", *fmt_s(s["operator_total_s"])],
            ["", "operator: planning (status.planningMillis)", *fmt_s(s["operator_planning_s"])],
            ["", "operator: all Running - planning", *fmt_s(s["operator_minus_planning_s"])],
            ["", "operator: first Deployment seen", *fmt_s(s["operator_first_deployment_s"])],
            ["", "operator: last Deployment seen", *fmt_s(s["operator_last_deployment_s"])],
            ["", "operator: fleet Ready=True seen", *fmt_s(s["operator_ready_condition_s"])],
            ["", "cleanup (namespace gone): plain", *fmt_s(s["plain_cleanup_s"])],
            ["", "cleanup (namespace gone): operator", *fmt_s(s["operator_cleanup_s"])],
            ["", "load1 during runs", *fmt_s(s["load1"])],
            [
                "",
                "(operator - planning) / plain  [target <= 1.5]",
                f"{s['ratio_operator_minus_planning_to_plain']:.2f}",
                "",
                "MET" if s["target_met"] else "NOT MET",
            ],
        ]
    out.append(table(rows, ["fleet", "measure", "median", "min", "max"]))
    if rep["missed_cycles"]:
        out += ["", "== missed-cycle rate (simulated): operator's nsga2 plan vs kube-scheduler's "
                "real placement (k8s-default fleet), median [min-max] over seeds"]  # fmt: skip
        mrows = [
            [
                r["fleet"],
                r["activity"],
                f"{r['seeds']}x{r['duration_s']:.0f}s",
                f"{100 * r['k8s_real_median']:.3f}% [{100 * r['k8s_real_min']:.3f}-"
                f"{100 * r['k8s_real_max']:.3f}]",
                f"{100 * r['nsga2_median']:.4f}% [{100 * r['nsga2_min']:.4f}-"
                f"{100 * r['nsga2_max']:.4f}]",
                f"{100 * r['reduction']:.1f}%"
                if r["reduction"] == r["reduction"]
                else "n/a (k8s median is 0)",
                "MET" if r["target_met"] else "NOT MET",
                f"{r['split_k8s_real']} vs {r['split_nsga2']}",
            ]
            for r in rep["missed_cycles"]
        ]
        out.append(
            table(
                mrows,
                [
                    "fleet",
                    "activity",
                    "seeds",
                    "k8s-default (real)",
                    "nsga2 (operator)",
                    "fewer misses [>=90%]",
                    "target",
                    "robot/edge/cloud k8s vs nsga2",
                ],
            )
        )
    for err in rep.get("errors") or []:
        out.append(f"\nFAILED: {err}")
    out.append(f"\noperator log: {rep.get('operator_log')}")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per fleet and path (median of)")
    ap.add_argument(
        "--large-runs", type=int, default=None, help="runs for the large fleet (default --runs)"
    )
    ap.add_argument("--robots", type=int, default=50, help="robots of the large fleet")
    ap.add_argument("--edges", type=int, default=20, help="edge nodes of the large fleet")
    ap.add_argument("--skip-large", action="store_true", help="warehouse fleet only")
    ap.add_argument("--skip-misses", action="store_true", help="latency only")
    ap.add_argument("--seeds", type=int, default=10, help="simulation seeds (warehouse)")
    ap.add_argument("--sim-seconds", type=float, default=120.0)
    ap.add_argument("--large-seeds", type=int, default=3, help="simulation seeds (large fleet)")
    ap.add_argument("--large-sim-seconds", type=float, default=60.0)
    ap.add_argument("--timeout", type=float, default=180.0, help="per run (x4 for the large)")
    ap.add_argument("--json", action="store_true", help="print the report as JSON instead")
    args = ap.parse_args(argv)
    if args.large_runs is None:
        args.large_runs = args.runs
    rep = bench(args)
    if args.json:
        print(json.dumps(rep, indent=1, default=str))
    else:
        print(format_report(rep))
    return 0


if __name__ == "__main__":
    sys.exit(main())
