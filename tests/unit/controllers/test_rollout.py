"""rollout(): where each desired Deployment stands, from the pods (their spec hash) and the
Deployments' status."""

from __future__ import annotations

from fogfleet.api.labels import ANNOTATION_SPEC_HASH, LABEL_INSTANCE
from fogfleet.controllers.status import rollout


def desired(name: str = "m", nodes: tuple[str, ...] = ("edge-1",), spec: str = "new") -> dict:
    return {
        "metadata": {"name": name, "annotations": {ANNOTATION_SPEC_HASH: spec}},
        "spec": {
            "template": {
                "spec": {
                    "affinity": {
                        "nodeAffinity": {
                            "requiredDuringSchedulingIgnoredDuringExecution": {
                                "nodeSelectorTerms": [
                                    {"matchExpressions": [{"values": list(nodes)}]}
                                ]
                            }
                        }
                    }
                }
            }
        },
    }


def deployment(spec: str = "new", done: bool = False) -> dict:
    dep = desired(spec=spec)
    dep["metadata"]["generation"] = 2
    dep["status"] = {
        "observedGeneration": 2 if done else 1,
        "updatedReplicas": 1 if done else 0,
        "availableReplicas": 1 if done else 0,
        "replicas": 1,
    }
    return dep


def pod(node: str = "edge-1", spec: str | None = "new", ready: bool = True) -> dict:
    annotations = {ANNOTATION_SPEC_HASH: spec} if spec else {}
    return {
        "metadata": {"name": "m-x", "labels": {LABEL_INSTANCE: "m"}, "annotations": annotations},
        "spec": {"nodeName": node},
        "status": {
            "phase": "Running",
            "conditions": [{"type": "Ready", "status": "True" if ready else "False"}],
        },
    }


def test_a_ready_pod_of_the_desired_spec_settles_before_the_deployment_status_says_so():
    roll = rollout([desired()], [deployment(done=False)], [pod()])
    assert roll.settled == ["m"] and roll.bound == {"m": "edge-1"}


def test_a_pod_of_an_older_spec_waits_for_the_deployment():
    roll = rollout([desired()], [deployment(done=False)], [pod(spec="old")])
    assert roll.waiting == ["m"] and not roll.settled


def test_a_pod_without_the_hash_settles_once_the_deployment_rolled_out():
    assert rollout([desired()], [deployment(done=True)], [pod(spec=None)]).settled == ["m"]
    assert rollout([desired()], [deployment(done=False)], [pod(spec=None)]).waiting == ["m"]


def test_a_pod_not_ready_or_on_another_node_is_not_settled():
    assert rollout([desired()], [deployment(done=True)], [pod(ready=False)]).waiting == ["m"]
    roll = rollout([desired()], [deployment(done=True)], [pod(), pod(node="edge-9")])
    assert roll.moving == ["m"]
