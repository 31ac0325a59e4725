"""A fleet as one plan sees it, and why each instance runs where it does.

``Live`` is a fleet's snapshot, its problem and the placement that runs: ``kubectl fogfleet``
rebuilds it from the API's objects (``commandline.kubectl.live.read_fleet``); the operator keeps
the one it planned (``controllers.fleet.explain``) and answers ``ExplanationRequest``s from it.
``why_of`` explains a module's instances on either, and ``why_doc`` is the document both print,
so the two answers are the same document.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.explain.alternatives import ModuleWhy, explain_module

from .problem import refused
from .snapshot import FleetSnapshot

__all__ = ["Live", "deployed_placement", "why_doc", "why_of"]

Doc = dict[str, Any]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Live:
    """A running fleet's snapshot, its problem, its deployed placement."""

    snapshot: FleetSnapshot
    problem: Problem  # unavailable nodes masked out
    unavailable: dict[int, str]  # node index -> why
    placement: I64  # deployed (I,), -1 where unknown

    @property
    def fleet(self) -> RobotFleet:
        return self.snapshot.fleet

    @property
    def with_limits(self) -> bool:
        return self.fleet.spec.scheduler.algorithm is not SchedulerName.ONBOARD

    @property
    def measured(self) -> Mapping[str, float]:
        """Module -> measured miss rate."""
        return self.snapshot.measured

    @property
    def status(self) -> Doc:
        return dict(self.snapshot.status)

    def refused(self, i: int) -> dict[int, Any]:
        """Instance i's refusals by node (``domain.build.refusals``)."""
        return dict(refused(self.snapshot, self.problem, i))


def why_of(live: Live, module: str, robot: str | None = None, limit: int = 50) -> ModuleWhy:
    """``scheduling.explain.alternatives.explain_module`` on the running fleet, with the
    measured miss rate."""
    spec = live.fleet.spec.scheduler
    w = explain_module(
        live.problem,
        live.placement,
        live.with_limits,
        module,
        robot=robot,
        objectives=[o.value for o in spec.objectives],
        refused=live.refused,
        unavailable=live.unavailable,
        held=live.snapshot.held,
        limit=limit,
    )
    return ModuleWhy(**{**w.__dict__, "measured_miss_rate": live.measured.get(module)})


def why_doc(w: ModuleWhy) -> Doc:
    """A ``ModuleWhy`` as the document ``-o json|yaml`` prints (camelCase, as kubectl)."""
    return {
        "fleet": w.fleet,
        "module": w.module,
        "predictedMissRate": w.predicted_miss_rate,
        "measuredMissRate": w.measured_miss_rate,
        "objectives": list(w.objectives),
        "planObjectives": w.values,
        "omittedInstances": w.omitted,
        "instances": [
            {
                "instance": i.label,
                "robot": i.robot,
                "replica": i.replica,
                "node": i.node,
                "tier": i.tier,
                "cpu": i.cpu,
                "predictedMiss": i.predicted_miss,
                "alternatives": [
                    {
                        "node": a.node,
                        "tier": a.tier,
                        "rule": a.rule,
                        "reason": a.reason,
                        **({"objectiveDeltas": a.deltas} if a.deltas else {}),
                    }
                    for a in i.alternatives
                ],
                **(
                    {
                        "split": {
                            "action": i.split[0],
                            "reason": i.split[1],
                            "alternatives": [{"action": n, "reason": r} for n, r in i.split[2]],
                        }
                    }
                    if i.split is not None
                    else {}
                ),
            }
            for i in w.instances
        ],
    }


def deployed_placement(problem: Problem, snapshot: FleetSnapshot) -> I64:
    """Where each instance runs (``FleetSnapshot.deployed``), by node index."""
    index: dict[str, int] = {}
    for j, nd in enumerate(problem.nodes):
        index.setdefault(nd.node_name, j)
        index.setdefault(nd.name, j)
    out = np.full(problem.n_instances, -1, dtype=np.int64)
    for i, inst in enumerate(problem.instances):
        node = snapshot.deployed.get((inst.robot, inst.module, inst.replica))
        if node is not None and node in index:
            out[i] = index[node]
    return out
