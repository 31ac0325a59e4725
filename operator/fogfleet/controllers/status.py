"""Build a RobotFleet's status (Kubernetes API conventions): conditions keyed by type with
CamelCase reasons and messages a person can act on, the placement table, objective values.

Pure functions of the plan and of what the cluster shows (Deployments and their pods).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from pydantic import BaseModel

from fogfleet.api.labels import LABEL_INSTANCE
from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.common import Condition
from fogfleet.domain.miss_rates import format_miss_rate
from fogfleet.render.deployments import hash_annotation
from fogfleet.render.manifestwork import managed_cluster_of
from fogfleet.snapshot.objects import scaling_status

__all__ = [
    "Rollout",
    "changed_parts",
    "complete",
    "condition",
    "find_condition",
    "finite",
    "merge_conditions",
    "miss_fields",
    "now",
    "pod_ready",
    "rollout",
    "same_status",
    "scaling_status",
    "set_conditions",
    "split_text",
    "wire",
    "wire_keys",
    "without_transition_times",
]

Obj = dict[str, Any]


def wire_keys(model: type[BaseModel]) -> tuple[str, ...]:
    """The camelCase keys of a status model: what one writer owns."""
    return tuple(f.alias or name for name, f in model.model_fields.items())


def wire(status: BaseModel) -> Obj:
    """A status model as it is written: the fields its writer set, camelCase (a None set
    removes the field in a merge patch). Each writer builds its part as the model and
    serialises it here, once."""
    out: Obj = status.model_dump(by_alias=True, exclude_unset=True, mode="json")
    return out


def complete(status: Obj, keys: Iterable[str]) -> Obj:
    """``status`` with every owned key, absent ones as None: the merge patch then removes a
    field a reconcile stopped writing instead of keeping it forever."""
    return {**{k: None for k in keys}, **status}


def split_text(tiers: Mapping[str, int]) -> str:
    """Instances on robots/edge/cloud, as "3/2/0" (``status.split`` of fleets and modules)."""
    return "/".join(str(tiers.get(t, 0)) for t in ("robot", "edge", "cloud"))


def now() -> str:
    """The current time as a status timestamp."""
    return timestamp()


def condition(
    type_: str, ok: bool | None, reason: str, message: str, generation: int | None
) -> Obj:
    """A condition as written, built as the API's ``Condition`` model (so a reason that is not
    one CamelCase word fails here, in the writer, not at the API server)."""
    built = Condition(
        type=type_,
        status="Unknown" if ok is None else ("True" if ok else "False"),
        reason=reason,
        message=message[:2000],
        observed_generation=generation,
    )
    return wire(built)


def find_condition(conditions: Iterable[Mapping[str, Any]] | None, type_: str) -> Obj | None:
    """The condition of type ``type_``, or None (apimachinery's ``meta.FindStatusCondition``)."""
    return next((dict(c) for c in conditions or () if c.get("type") == type_), None)


def set_conditions(
    old: Iterable[Mapping[str, Any]] | None,
    new: Sequence[Obj],
    keep: Callable[[str], bool] = lambda _type: True,
) -> list[Obj]:
    """``new`` set into ``old``, as apimachinery's ``meta.SetStatusCondition`` sets one: each
    new condition keeps its old ``lastTransitionTime`` while its status is unchanged and gets
    the current time when it changes. The old conditions of other types follow, those whose
    type ``keep`` accepts (default: all of them). The one way every status writer merges its
    conditions."""
    before = [dict(c) for c in old or ()]
    ours = {c["type"] for c in new}
    out = []
    for c in new:
        prev = find_condition(before, c["type"])
        same = prev is not None and prev.get("status") == c["status"]
        stamp = prev.get("lastTransitionTime") if prev is not None and same else None
        out.append({**c, "lastTransitionTime": stamp or now()})
    return out + [c for c in before if c.get("type") not in ours and keep(str(c.get("type")))]


def merge_conditions(old: Iterable[Mapping[str, Any]] | None, new: Sequence[Obj]) -> list[Obj]:
    """``new`` as the whole list of conditions: ``set_conditions`` dropping the old others."""
    return set_conditions(old, new, keep=lambda _type: False)


def without_transition_times(conditions: Any) -> list[Obj]:
    """Conditions as compared between reconciles: a new stamp alone is no change."""
    return [{k: v for k, v in c.items() if k != "lastTransitionTime"} for c in conditions or []]


def changed_parts(old: Mapping[str, Any], new: Mapping[str, Any]) -> Obj:
    """The top-level fields of ``new`` that differ from ``old`` (None for one ``new`` drops):
    a merge patch of these leaves the rest as it is, so an unchanged large field (a 1000-robot
    fleet's placement) is not sent again at every rollout step."""
    return {k: v for k, v in new.items() if old.get(k) != v}


def same_status(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Equal apart from timestamps (so an idle reconcile patches nothing)."""

    def strip(s: Mapping[str, Any]) -> Any:
        out = {k: v for k, v in s.items() if k != "lastPlanTime" and v is not None}
        out["conditions"] = without_transition_times(s.get("conditions"))
        return out

    return bool(strip(old) == strip(new))


class Rollout:
    """Where each desired Deployment stands, from the Deployments and pods the cluster shows."""

    def __init__(self) -> None:
        self.settled: list[str] = []  # running where planned
        self.waiting: list[str] = []  # not yet running anywhere
        self.moving: list[str] = []  # still running elsewhere; its new pod is on the way
        self.bound: dict[str, str] = {}  # Deployment name -> node of its running pod


def pod_ready(pod: Mapping[str, Any]) -> bool:
    """Running, Ready (or not reporting readiness) and not being deleted."""
    st = pod.get("status") or {}
    if (pod.get("metadata") or {}).get("deletionTimestamp") or st.get("phase") != "Running":
        return False
    conds = {c.get("type"): c.get("status") for c in st.get("conditions") or []}
    return bool(conds.get("Ready", "True") == "True")


def affinity_nodes(dep: Mapping[str, Any]) -> list[str]:
    try:
        values: list[str] = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"]
        return values
    except (KeyError, IndexError, TypeError):
        return []


def _deployment_done(dep: Mapping[str, Any], want_hash: str | None) -> bool:
    meta = dep.get("metadata") or {}
    if want_hash and hash_annotation(dep) != want_hash:
        return False
    st = dep.get("status") or {}
    replicas = (dep.get("spec") or {}).get("replicas", 1)
    return bool(
        st.get("observedGeneration", 0) >= meta.get("generation", 0)
        and st.get("updatedReplicas", 0) >= replicas
        and st.get("availableReplicas", 0) >= replicas
        and st.get("replicas", 0) <= replicas
    )


def rollout(desired: Sequence[Obj], deployments: Sequence[Obj], pods: Sequence[Obj]) -> Rollout:
    """Compare the desired Deployments with the cluster's Deployments and running pods.

    A module is settled when it runs only on its planned nodes and either a ready pod carries
    the desired spec hash (rendered into the pod template) or its Deployment reports the
    desired spec rolled out (pods from before the hash was on pods). One in a managed cluster
    (read back from its ManifestWork) is settled when the work's feedback says so."""
    by_name = {d["metadata"]["name"]: d for d in deployments}
    running: dict[str, list[str]] = {}
    current: dict[str, set[str]] = {}  # instance -> nodes of ready pods of the desired spec
    wanted = {w["metadata"]["name"]: hash_annotation(w) for w in desired}
    for pod in pods:
        meta = pod.get("metadata") or {}
        inst = (meta.get("labels") or {}).get(LABEL_INSTANCE)
        node = (pod.get("spec") or {}).get("nodeName")
        if inst and node and pod_ready(pod):
            running.setdefault(inst, []).append(node)
            if wanted.get(inst) is not None and hash_annotation(pod) == wanted[inst]:
                current.setdefault(inst, set()).add(node)
    out = Rollout()
    for want in desired:
        name = want["metadata"]["name"]
        have = by_name.get(name)
        nodes = running.get(name, [])
        allowed = set(affinity_nodes(want))
        if have is not None and managed_cluster_of(have):
            # in a managed cluster: no pod here; its work's feedback is its rollout
            if _deployment_done(have, wanted[name]):
                out.settled.append(name)
                out.bound[name] = min(allowed, default="")
            else:
                out.waiting.append(name)
            continue
        good = [n for n in nodes if n in allowed]
        if good:
            out.bound[name] = good[0]
        rolled_out = bool(current.get(name, set()) & allowed) or (
            have is not None and _deployment_done(have, wanted[name])
        )
        if rolled_out and nodes and set(nodes) <= allowed:
            out.settled.append(name)
        elif nodes and not set(nodes) <= allowed:
            out.moving.append(name)
        else:
            out.waiting.append(name)
    return out


def finite(x: float | None) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), 6)


def miss_fields(rate: float | None) -> tuple[float | None, str | None]:
    """A miss rate as a status shows it (``...MissRate`` and ``...Miss``, predicted or
    measured): the fraction rounded to 1e-6 and the text people read (``format_miss_rate``;
    it says "<0.0001%" where the fraction reads 0); both None for no rate."""
    value = finite(rate)
    if value is None or rate is None:
        return None, None
    return value, format_miss_rate(rate)
