"""`make demo`, the cluster part: the warehouse fleet on the local control plane.

Starts the control plane if needed (building its tools the first time), installs the CRDs, runs
the operator (`fogfleet run`) against it, applies manifests/examples/warehouse/ in a namespace
of its own, waits until the fleet is Ready (every pod Running on its planned node, bound by the
real kube-scheduler) and prints `kubectl get robotfleets` and the placement. It cleans up the
namespace and stops the operator afterwards; the cluster keeps running (`make cluster-down`).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from e2e.bed import ensure_up  # noqa: E402
from e2e.bed.kube import Kube, guard_kubeconfig  # noqa: E402
from e2e.bed.operator_fixtures import Operator, conditions, example_docs, install_crds  # noqa: E402
from fogfleet.controllers.ros import is_ros_object  # noqa: E402

NAMESPACE = "fogfleet-demo"
TIMEOUT_SECONDS = 240


def main() -> int:
    cluster = ensure_up()
    server = guard_kubeconfig(cluster.kubeconfig, expected_server=cluster.api_server)
    kubectl = str(cluster.bin_dir / "kubectl")
    kube = Kube(cluster.kubeconfig, server, kubectl, False, cluster)
    install_crds(kube)
    kube.kubectl("delete", "namespace", NAMESPACE, "--ignore-not-found", "--wait=true")
    kube.kubectl("create", "namespace", NAMESPACE)
    log = Path(tempfile.mkdtemp(prefix="fogfleet-demo-")) / "operator.log"
    operator = Operator(cluster.kubeconfig, [NAMESPACE], log).start()
    try:
        operator.wait_live()
        started = time.monotonic()
        kube.apply(example_docs("warehouse", NAMESPACE), NAMESPACE)
        fleet: dict = {}
        while time.monotonic() - started < TIMEOUT_SECONDS:
            fleet = kube.kubectl_json("get", "robotfleet", "warehouse", "-n", NAMESPACE)
            ready = conditions(fleet).get("Ready", {})
            if ready.get("status") == "True":
                break
            time.sleep(1)
        else:
            print(f"The fleet did not become Ready in {TIMEOUT_SECONDS} s:", file=sys.stderr)
            print(conditions(fleet), file=sys.stderr)
            print(operator.logs(), file=sys.stderr)
            return 1
        elapsed = time.monotonic() - started
        print(kube.kubectl("get", "robotfleets", "-n", NAMESPACE).stdout)
        status = fleet["status"]
        pods = kube.kubectl_json("get", "pods", "-n", NAMESPACE)["items"]
        bound = Counter(
            p["spec"].get("nodeName") for p in pods if p["status"].get("phase") == "Running"
        )
        print(f"{'ROBOT':9} {'MODULE':24} {'NODE':9} {'TIER':6} CPU")
        for row in status["placement"]:
            print(
                f"{row['robot']:9} {row['module']:24} {row['node']:9} {row['tier']:6} {row['cpu']}"
            )
        print()
        servers = [p for p in pods if is_ros_object(p)]
        print(
            f"{len(pods) - len(servers)} module pods and {len(servers)} ROS discovery servers "
            f"Running on {len(bound)} nodes, bound by kube-scheduler, "
            f"{elapsed:.1f} s after kubectl apply (planning {status.get('planningMillis')} ms)"
        )
        print(f"Predicted missed-cycle rate: {status.get('predictedMissRate')}")
        print(f"Choice: {status.get('choiceReason')}")
        return 0
    finally:
        operator.stop()
        kube.kubectl(
            "delete", "namespace", NAMESPACE, "--ignore-not-found", "--wait=false", check=False
        )


if __name__ == "__main__":
    sys.exit(main())
