"""`make demo`, the cluster part: the warehouse fleet on the local bed, left running.

Starts the bed if needed (building its tools the first time), installs fogfleet the way the
README's "Install into a cluster" says (the Helm chart; the operator runs in-cluster, on a
real node of the bed), applies ``manifests/examples/warehouse/`` as a user would, waits until
the fleet is Ready (every pod Running on its planned node, bound by the real kube-scheduler)
and prints ``kubectl get robotfleets``, the placement and the commands to go on with. Nothing
is deleted: the bed, the operator and the fleet keep running until ``make cluster-down``.

    python e2e/demo.py            # the demo
    python e2e/demo.py remove     # uninstall the demo's release and its example namespaces
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from e2e.bed import ensure_up  # noqa: E402
from e2e.bed.cluster import Cluster, running  # noqa: E402
from e2e.bed.kube import Kube, guard_kubeconfig  # noqa: E402
from e2e.bed.operator_fixtures import conditions  # noqa: E402
from fogfleet.controllers.ros import is_ros_object  # noqa: E402

RELEASE, SYSTEM = "fogfleet", "fogfleet-system"
EXAMPLE = "manifests/examples/warehouse/"
NAMESPACE = "warehouse"  # the example's own 00-namespace.yaml
DEMO_NAMESPACES = ("warehouse", "warehouse-lite", "single-robot", "shared-detector", "pod-template")
TIMEOUT_SECONDS = 300
PROGRESS_SECONDS = 10


def say(msg: str) -> None:
    print(f"[demo] {msg}", flush=True)


def helm(*args: str) -> None:
    """The bed's helm (``harness.py helm``) with the bed's kubeconfig; its output streams."""
    cmd = [sys.executable, str(ROOT / "e2e" / "bed" / "harness.py"), "helm", *args]
    subprocess.run(cmd, check=True, cwd=ROOT)


def install(kube: Kube) -> None:
    """The README's Helm install (upgrade --install, so a second demo finds it in place)."""
    say(f"helm install {RELEASE} charts/fogfleet -n {SYSTEM} --create-namespace  (the README's)")
    t0 = time.monotonic()
    helm("upgrade", "--install", "--take-ownership", RELEASE, "charts/fogfleet", "-n", SYSTEM,
         "--create-namespace",
         "--wait", "--timeout", "300s")  # fmt: skip
    pods = kube.kubectl_json(
        "get", "pods", "-n", SYSTEM, "-l", "app.kubernetes.io/component=operator"
    )["items"]
    where = sorted({p["spec"].get("nodeName", "?") for p in pods})
    say(f"operator: {len(pods)} replicas Running on {', '.join(where)} "
        f"({time.monotonic() - t0:.0f} s)")  # fmt: skip


def wait_ready(kube: Kube) -> tuple[dict, float]:
    started = time.monotonic()
    say(f"kubectl apply -f {EXAMPLE}")
    kube.kubectl("apply", "-f", str(ROOT / EXAMPLE))
    fleet: dict = {}
    report = started + PROGRESS_SECONDS
    while time.monotonic() - started < TIMEOUT_SECONDS:
        fleet = kube.kubectl_json("get", "robotfleet", "warehouse", "-n", NAMESPACE)
        ready = conditions(fleet).get("Ready", {})
        if ready.get("status") == "True":
            return fleet, time.monotonic() - started
        if time.monotonic() > report:
            say(f"... waiting for the fleet: Ready={ready.get('status', '-')} "
                f"{ready.get('reason', '')} {time.monotonic() - started:.0f} s")  # fmt: skip
            report += PROGRESS_SECONDS
        time.sleep(1)
    raise SystemExit(
        f"The fleet did not become Ready in {TIMEOUT_SECONDS} s: {conditions(fleet)}\n"
        f"Operator logs: kubectl logs -n {SYSTEM} -l app.kubernetes.io/component=operator"
    )


def show(kube: Kube, fleet: dict, elapsed: float) -> None:
    print(kube.kubectl("get", "robotfleets", "-n", NAMESPACE).stdout)
    status = fleet["status"]
    pods = kube.kubectl_json("get", "pods", "-n", NAMESPACE)["items"]
    running_on = [p["spec"].get("nodeName") for p in pods if p["status"].get("phase") == "Running"]
    bound = Counter(running_on)
    print(f"{'ROBOT':9} {'MODULE':24} {'NODE':9} {'TIER':6} CPU")
    for row in status["placement"]:
        print(f"{row['robot']:9} {row['module']:24} {row['node']:9} {row['tier']:6} {row['cpu']}")
    print()
    servers = [p for p in pods if is_ros_object(p)]
    print(
        f"{len(pods) - len(servers)} module pods and {len(servers)} ROS discovery servers "
        f"Running on {len(bound)} nodes, bound by kube-scheduler, "
        f"{elapsed:.1f} s after kubectl apply (planning {status.get('planningMillis')} ms)"
    )
    print(f"Choice: {status.get('choiceReason')}")


def next_steps(cluster: Cluster) -> str:
    """What to type next, in the user's own shell."""
    harness = "python3 e2e/bed/harness.py"
    robot = next((n for n in cluster.real_nodes if "robot" in n), "bed-robot-1")
    return f"""
The bed, the operator (in-cluster, Helm release {RELEASE} in {SYSTEM}) and the fleet keep
running. In your own shell:

  export KUBECONFIG={cluster.kubeconfig}
  export PATH={cluster.bin_dir}:$PATH             # the bed's kubectl and helm
  kubectl get robotfleets -A                      # without the exports: make kubectl ARGS="..."
  kubectl get robotfleets -n {NAMESPACE} -w            # watch the fleet
  kubectl describe robotfleet warehouse -n {NAMESPACE}  # conditions, choiceReason, Events
  kubectl get computenodes                        # what each node holds
(The warehouse's nodes are kwok's: its pods are bound and Running, but no container runs.)

Run a fleet on the bed's real nodes (real containers, real ROS 2 traffic) and cut a robot's link:
  kubectl apply -f manifests/examples/warehouse-lite/
  kubectl get robotfleets -n warehouse-lite -w
  kubectl logs -n warehouse-lite -l app.kubernetes.io/managed-by=fogfleet --prefix --tail=1 \\
      --max-log-requests=20                       # each module logs a line every 10 s
  {harness} link {robot} --loss 100%     # cut the robot off the edge
  kubectl logs -n warehouse-lite -l fogfleet.io/robot={robot} --prefix --tail=1  # messages stop
  {harness} link {robot} --reset
(With a fallback in the fleet's spec, the robot's standbys take over: docs/ros2.md.)

Every example applies on its own: kubectl apply -f manifests/examples/<name>/
(shared-detector plans onto the warehouse's robots robot-1..5: it is Infeasible, and says why,
until you free them: kubectl delete namespace warehouse)
Stop everything: make cluster-down (it says what, if anything, it could not remove)
"""


def remove() -> int:
    """Undo the demo on a running bed: the release and the examples' namespaces."""
    cluster = running()
    if cluster is None:
        return 0
    kube = _kube(cluster)
    listed = subprocess.run(
        [sys.executable, str(ROOT / "e2e" / "bed" / "harness.py"), "helm", "list", "-n", SYSTEM,
         "-q"], capture_output=True, text=True, check=False, cwd=ROOT,
    ).stdout.split()  # fmt: skip
    if RELEASE in listed:
        say(f"removing the demo: helm uninstall {RELEASE} -n {SYSTEM}")
        helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
    for ns in DEMO_NAMESPACES:
        kube.kubectl("delete", "namespace", ns, "--ignore-not-found", "--wait=false", check=False)
    return 0


def _kube(cluster: Cluster) -> Kube:
    server = guard_kubeconfig(cluster.kubeconfig, expected_server=cluster.api_server)
    return Kube(cluster.kubeconfig, server, str(cluster.bin_dir / "kubectl"), False, cluster)


def main(argv: list[str]) -> int:
    if argv[:1] == ["remove"]:
        return remove()
    t0 = time.monotonic()
    cluster = ensure_up()
    kube = _kube(cluster)
    install(kube)
    fleet, elapsed = wait_ready(kube)
    show(kube, fleet, elapsed)
    print(next_steps(cluster))
    say(f"done in {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
