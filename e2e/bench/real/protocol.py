"""The benchmark's protocol, fixed before any result (issue 33): which arms run how often, in
what order, for how long, and what is measured.

* **Arms** (issue 49: nsga2 x6, nsga2-static x6, k8s-default x6, k8s-requests x6, onboard x1,
  about 80 minutes here). ``nsga2`` (the operator's plan, closed loop on; planner seeds
  1..n), ``nsga2-static`` (the paper's a-priori GA: the first plan, no closed loop; the loop's
  yardstick), ``k8s-default`` (plain Deployments that kube-scheduler binds, requesting the
  modules' declared CPU; a fresh namespace each run so each is a fresh draw of its
  placement), ``k8s-requests`` (the same Deployments, each module requesting what it needs on
  the reference hardware, ``scenario.honest_requests``, with kube-scheduler's default
  scoring) and ``onboard`` (every module on its robot; one sanity run, its figures are known).
* **Blocks.** Runs go in blocks; an arm of n runs has one run in each of n blocks, spread
  evenly (with six blocks, every six-run arm is in every block; onboard in the first). The
  order inside a block alternates (forward in even blocks, reversed in odd ones), so no arm
  always runs first, or always right after the same other arm.
* **Timing.** A warm-up after the fleet is Ready (long enough for the closed loop's re-plan:
  30 s measured + 10 s of drift, checked every 30 s), then one window between two counter
  snapshots. A plan that changes inside the window fails the run; a failed run is recorded,
  never dropped.
* **Pending** (fixed 2026-11-29, before the first run with k8s-requests). In the
  kube-scheduler arms an instance whose pod kube-scheduler cannot bind anywhere (Pending,
  Unschedulable: its request fits no node's room) does not fail the run: it missed every cycle
  of the window, in the measurement and in the simulation alike (the cycles it was due,
  ``window / cycle time``), and its placement is recorded as ``Pending``. That is what a user
  with those requests gets. In the planner arms a pod left Pending fails the run.
* **Endpoint.** Primary: missed / cycles pooled over every human-pose-estimation and
  scene-segmentation instance of the run (the paper's Fig. 9b metric). Secondary: the mean
  over modules (the planner's and the simulator's figure), and each module's rate.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

__all__ = [
    "ARMS",
    "DEFAULT_RUNS",
    "PENDING",
    "PERCEPTION",
    "PRIMARY",
    "REQUESTS",
    "STATIC",
    "Protocol",
    "ScheduledRun",
    "parse_arms",
]

NSGA2, K8S, ONBOARD, STATIC = "nsga2", "k8s-default", "onboard", "nsga2-static"
REQUESTS = "k8s-requests"  # k8s-default's Deployments with honest CPU requests (issue 49)
ARMS = (NSGA2, STATIC, K8S, REQUESTS, ONBOARD)  # the order of every table and of a block
DEFAULT_RUNS = {NSGA2: 6, STATIC: 6, K8S: 6, REQUESTS: 6, ONBOARD: 1}
PRIMARY = "perception"
PENDING = "Pending"  # the placement recorded for an instance kube-scheduler could not bind
PERCEPTION = ("human-pose-estimation", "scene-segmentation")


@dataclass(frozen=True)
class ScheduledRun:
    """One run of the schedule: its arm, the planner seed, its block and place in the order."""

    arm: str
    seed: int  # nsga2: spec.scheduler.seed; every arm: the simulator's seed
    block: int
    position: int  # 0-based place in the whole schedule

    @property
    def algorithm(self) -> str:
        """The RobotFleet's spec.scheduler.algorithm (nsga2-static plans with nsga2,
        k8s-requests hands the fleet to kube-scheduler as k8s-default does)."""
        return {STATIC: NSGA2, REQUESTS: K8S}.get(self.arm, self.arm)

    @property
    def kube_scheduler(self) -> bool:
        """kube-scheduler binds the run's pods (an unbindable one stays Pending and misses)."""
        return self.algorithm == K8S

    @property
    def closed_loop(self) -> bool:
        return self.arm != STATIC


@dataclass(frozen=True)
class Protocol:
    window_s: float = 60.0
    warmup_s: float = 90.0
    runs: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_RUNS))

    @property
    def blocks(self) -> int:
        return max(self.runs.values(), default=0)

    def schedule(self) -> list[ScheduledRun]:
        """Every run in the order it runs (see the module docstring)."""
        n_blocks = self.blocks
        members: list[list[str]] = [[] for _ in range(n_blocks)]
        for arm in ARMS:
            n = self.runs.get(arm, 0)
            for k in range(n):  # spread evenly: block floor(k * blocks / n)
                members[k * n_blocks // n].append(arm)
        out: list[ScheduledRun] = []
        seen: dict[str, int] = {}
        for b, arms in enumerate(members):
            for arm in arms if b % 2 == 0 else reversed(arms):
                seen[arm] = seen.get(arm, 0) + 1
                out.append(ScheduledRun(arm, seen[arm], b, len(out)))
        return out

    def as_json(self) -> dict[str, object]:
        return {
            "windowSeconds": self.window_s,
            "warmupSeconds": self.warmup_s,
            "arms": {a: self.runs[a] for a in ARMS if self.runs.get(a)},
            "blocks": self.blocks,
            "order": "blocks; inside a block forward in even blocks, reversed in odd ones",
            "primaryEndpoint": PRIMARY,
            "perceptionModules": list(PERCEPTION),
        }


def parse_arms(text: str) -> dict[str, int]:
    """``nsga2=6,k8s-default=6`` -> runs per arm; an unknown arm or count names itself."""
    out: dict[str, int] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        arm, _, count = part.partition("=")
        if arm not in ARMS:
            raise ValueError(f"--arms: unknown arm {arm!r}; choose from {', '.join(ARMS)}")
        try:
            n = int(count) if count else 1
        except ValueError:
            raise ValueError(f"--arms: {arm}={count!r} is not a whole number") from None
        if n < 1:
            raise ValueError(f"--arms: {arm}={n}: at least 1 run")
        out[arm] = n
    if not out:
        raise ValueError("--arms: no arm given")
    return out
