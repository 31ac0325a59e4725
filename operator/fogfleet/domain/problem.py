"""The placement problem of one fleet, as immutable numpy arrays (the scheduling core's input).

One *instance* is one gene (ARCHITECTURE.md): a per-robot module yields one instance per robot,
a shared module one instance per replica. Each gene's value is a node index; ``allowed[i]`` is
the gene space C_i of multi-robot-edge-cloud-scheduling III-E, narrowed by the taxonomy
(III-A/B) and the hard requirements (devices, GPU, real-time kernel, privacy, tier).

Two *allocations* give each (instance, node) pair its CPU figures:

- ``limits`` ("GA-based with limits", IV-B): requests = limits = a CPU amount chosen per
  hardware type from the profile (Fig. 3), so modules never contend for CPU on a node.
- ``nominal`` (what a plain Deployment gets): the module's nominal request, no limit, so while
  active it uses the parallelism its profile shows on that hardware and contends with others.

Where the site is short of CPU, a plan may *degrade* instances: guarantee one only a smaller
profiled CPU than the limits pick (a rung of its ``Ladder``) as its request, keeping the pick as
its limit, so it runs at full speed while its node has idle CPU and shares what is left when
the node is busy (the contention model predicts the misses). ``priority`` orders who degrades
first (``with_levels``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.dnn import Dnn

__all__ = [
    "TIER_CODE",
    "Allocation",
    "Instance",
    "Ladder",
    "LazyLadder",
    "NodeInfo",
    "Problem",
    "freeze",
]

F64 = NDArray[np.float64]
_A = TypeVar("_A", bound="np.ndarray[Any, Any]")


def freeze(a: _A) -> _A:
    """Make an array read-only: a Problem is shared between threads and never changes."""
    a.setflags(write=False)
    return a


TIER_CODE = {Tier.ROBOT: 0, Tier.EDGE: 1, Tier.CLOUD: 2}
# The limit chosen per hardware type is the smallest profiled CPU whose mean + 2 std execution
# time, plus the transfer time, stays within this share of the cycle time (the rest is slack
# for jitter). A larger limit would waste reserved cores; a smaller one would miss cycles.
EXEC_SHARE_OF_CYCLE = 0.9


@dataclass(frozen=True)
class NodeInfo:
    name: str  # ComputeNode name
    node_name: str  # Kubernetes Node name
    tier: Tier
    hardware_type: str
    # spec.speedFactor: 'default' profile rows run this many times faster here (pairs.rows_for)
    speed_factor: float = 1.0


@dataclass(frozen=True)
class Instance:
    robot: str  # robot ComputeNode name, "" for a shared replica
    module: str
    replica: int  # 0 for per-robot instances


@dataclass(frozen=True)
class Allocation:
    """Per (instance, node): CPU request, CPU used while active, execution-time mean/std (s)."""

    cpu_request: F64  # (I, N) cores
    cpu_use: F64  # (I, N) cores while active
    exe_mean: F64  # (I, N) seconds, uncontended
    exe_std: F64  # (I, N) seconds
    has_limit: bool


@dataclass(frozen=True)
class Ladder:
    """The profiled CPU amounts at or below the limits pick, per (instance, node): rung 0 is the
    pick, rung k the k-th next smaller profiled CPU of that hardware type (Fig. 3's rows),
    padded with the smallest; ``depth[i, j]`` rungs exist below the pick."""

    cpu: F64  # (I, N, K) cores
    mean: F64  # (I, N, K) seconds
    std: F64  # (I, N, K) seconds
    depth: NDArray[np.int64]  # (I, N)


class LazyLadder:
    """A :class:`Ladder` built on first use, then shared.

    Three (I, N, K) arrays are the bulk of a large fleet's problem (at 1000 robots on 400 edge
    nodes, 0.83 of its 1.68 GiB), yet only a fleet short of CPU degrades: most plans never read
    them. The problems derived from one build (``dataclasses.replace``: masked nodes, levels)
    hold the same LazyLadder, so it is built at most once per build; concurrent first uses may
    each build it, the first result stays. ``digest`` identifies what it is built from (a plan's
    fingerprint must change when a smaller profiled CPU does, without building the ladder).
    """

    def __init__(self, build: Callable[[], Ladder | None], digest: bytes) -> None:
        self.digest = digest
        self._build: Callable[[], Ladder | None] | None = build
        self._ladder: Ladder | None = None
        self._lock = threading.Lock()

    @property
    def built(self) -> bool:
        """Whether it was built (read) already."""
        with self._lock:
            return self._build is None

    def get(self) -> Ladder | None:
        """The ladder (None: nothing may degrade)."""
        with self._lock:
            build = self._build
        if build is None:
            return self._ladder
        ladder = build()
        with self._lock:
            if self._build is not None:
                self._ladder, self._build = ladder, None  # drop what the build held
            return self._ladder


@dataclass(frozen=True)
class Problem:
    fleet: str
    namespace: str
    nodes: tuple[NodeInfo, ...]
    instances: tuple[Instance, ...]
    tier: NDArray[np.int64]  # (N,) 0 robot, 1 edge, 2 cloud
    capacity: F64  # (N, 3) cpu cores, memory bytes, gpus (allocatable minus reserve)
    cost: F64  # (N,) per core-hour
    power: F64  # (N, 4) battery Wh, idle W, per-core W, radio W per Mbps (robots; else 0)
    uplink_bandwidth: F64  # (N,) bit/s of each node's own uplink
    home: NDArray[np.int64]  # (I,) the instance's robot node index, -1 for shared replicas
    allowed: NDArray[np.bool_]  # (I, N) gene spaces
    activation: F64  # (I,) fraction of time active (Table II avg. execution rate)
    cycle: F64  # (I,) expected cycle time, seconds
    memory: F64  # (I,) bytes
    gpu: F64  # (I,)
    net_mean: F64  # (I, N) t_in + t_out mean, seconds (eq. 4)
    net_std: F64  # (I, N) seconds
    traffic: F64  # (I,) bit/s exchanged with the robot when not on board
    limits: Allocation
    nominal: Allocation
    current: NDArray[np.int64]  # (I,) current node index, -1 where unknown
    reasons: dict[int, str] = field(default_factory=dict)  # instance -> why nowhere fits
    priority: NDArray[np.int64] | None = None  # (I,) higher degrades later; None: all alike
    ladder_source: LazyLadder | None = None  # None: no smaller CPU profiled (see ``ladder``)
    levels: NDArray[np.int64] | None = None  # (I,) rungs taken below the pick; None: none
    preferred: NDArray[np.bool_] | None = None  # (I, N) node's tier preferred; None: no wishes
    fallback: NDArray[np.bool_] | None = None  # (I,) keeps an on-board fallback; None: none
    fallback_row: F64 | None = None  # (I, 3) cpu, mean, std (s) its standby runs with at home
    # standbys that run a lighter variant module (fallback mode variant): its own CPU row
    # (not capped by the module's own request at home: the module may not even run there),
    # its cycle time, its memory and GPUs; None: every standby runs the module itself
    fallback_variant: NDArray[np.bool_] | None = None  # (I,)
    fallback_cycle: F64 | None = None  # (I,) the standby's cycle time, seconds
    fallback_need: F64 | None = None  # (I, 2) memory bytes, gpus the standby holds
    # split networks (SoftwareModule.spec.dnn): the action RoboEC2's rule takes with the tail on
    # each node (contract.dnnsplit: 0 whole off board, k split point k, n+1 the local model at
    # home); -1 where the instance is not a split network's or may not run; None: none is
    dnn_action: NDArray[np.int64] | None = None  # (I, N)
    split_models: Mapping[str, Dnn] | None = None  # module -> its network (spec.dnn)
    uplink_latency: F64 | None = None  # (N,) one-way latency of each node's uplink, seconds

    @property
    def n_instances(self) -> int:
        return len(self.instances)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def ladder(self) -> Ladder | None:
        """The degradation ladder (built on first use); None: nothing can degrade."""
        return None if self.ladder_source is None else self.ladder_source.get()

    def allocation(self, with_limits: bool) -> Allocation:
        return self.limits if with_limits else self.nominal

    @cached_property
    def module_index(self) -> NDArray[np.int64]:
        """(I,) the position of each instance's module in ``module_names``."""
        index = {m: k for k, m in enumerate(self.module_names)}
        return freeze(np.array([index[inst.module] for inst in self.instances], dtype=np.int64))

    @cached_property
    def module_names(self) -> tuple[str, ...]:
        """The fleet's modules, in the order of their first instance."""
        return tuple(dict.fromkeys(inst.module for inst in self.instances))

    @property
    def degraded(self) -> bool:
        return self.levels is not None and bool(np.any(self.levels > 0))

    def with_levels(self, levels: NDArray[np.int64] | None) -> Problem:
        """This problem with instance ``i``'s limits taken ``levels[i]`` rungs down its ladder
        (clamped per node to the rungs that exist); ``None`` or all zeros: unchanged."""
        # the ladder is read only when some instance takes a rung (reading it builds it)
        if levels is None or not np.any(levels > 0) or self.ladder is None:
            return (
                self if self.levels is None else replace(self, limits=self._rung(None), levels=None)
            )
        lv = np.asarray(levels, dtype=np.int64)
        return replace(self, limits=self._rung(lv), levels=freeze(lv.copy()))

    def _rung(self, levels: NDArray[np.int64] | None) -> Allocation:
        lad = self.ladder
        assert lad is not None
        # a degraded instance is guaranteed (requests) the rung's CPU and may burst to the
        # pick (limits): alone on its node it runs as fast as its deadline needs; when the
        # node is busy, it shares what is left (the contention model slows it down)
        use = np.where(self.allowed, lad.cpu[:, :, 0], 0.0)
        request = use
        if levels is not None and (down := np.flatnonzero(levels > 0)).size:
            # only the rows that take a rung differ from the pick
            k = np.minimum(levels[down, None], lad.depth[down])
            rung = np.take_along_axis(lad.cpu[down], k[:, :, None], axis=2)[:, :, 0]
            request = use.copy()
            request[down] = np.where(self.allowed[down], rung, 0.0)
        mean = np.where(self.allowed, lad.mean[:, :, 0], np.inf)
        std = np.where(self.allowed, lad.std[:, :, 0], 0.0)
        return Allocation(freeze(request), freeze(use), freeze(mean), freeze(std), True)

    @cached_property
    def fallback_rows(self) -> NDArray[np.int64]:
        """Instances with an on-board fallback (``domain.build`` gives one only to an instance
        its robot may run: that stays so while the robot is unavailable and masked out)."""
        if self.fallback is None:
            return np.zeros(0, dtype=np.int64)
        return freeze(np.flatnonzero(self.fallback & (self.home >= 0)).astype(np.int64))

    def fallback_share(self, allocation: Allocation) -> F64:
        """(I, 3) cpu, memory, gpus each instance with a fallback holds on its robot.

        It needs that share on its robot wherever it runs: on board it runs there, off board
        its standby must be able to take over there without asking the control plane (issue
        13; RoboEC2's local path). The standby runs with ``fallback_row`` (at most the CPU the
        instance would get on board); on board the instance needs the rest of its request
        on top (``held_at_home``: only that rest counts as its demand there).
        """
        out = np.zeros((self.n_instances, 3))
        rows = self.fallback_rows
        if rows.size:
            homes = self.home[rows]
            cpu = allocation.cpu_request[rows, homes]
            if self.fallback_row is not None:
                cpu = np.minimum(cpu, self.fallback_row[rows, 0])
            out[rows, 0] = cpu
            out[rows, 1] = self.memory[rows]
            out[rows, 2] = self.gpu[rows]
            if self.fallback_variant is not None and self.fallback_row is not None:
                v = rows[self.fallback_variant[rows]]  # a variant holds what it runs with
                out[v, 0] = self.fallback_row[v, 0]
                if self.fallback_need is not None:
                    out[v, 1:] = self.fallback_need[v]
        return out

    def fallback_reserve(self, allocation: Allocation) -> F64:
        """(N, 3) what each robot holds for its modules' on-board fallbacks, whatever the plan
        (the sum of their ``fallback_share``)."""
        out = np.zeros((self.n_nodes, 3))
        rows = self.fallback_rows
        if rows.size:
            np.add.at(out, self.home[rows], self.fallback_share(allocation)[rows])
        return out

    @cached_property
    def standing_by(self) -> NDArray[np.bool_]:
        """(I,) instances whose robot holds a fallback for them: off board, a standby runs
        there (``render``), and a lost link leaves the standby (``scheduling.fallback``)."""
        out = np.zeros(self.n_instances, dtype=bool)
        out[self.fallback_rows] = True
        return freeze(out)

    @cached_property
    def held_at_home(self) -> NDArray[np.bool_]:
        """(I,) instances part of whose demand on their home node (``fallback_share``) is in
        ``fallback_reserve``: there they count only the rest. Not a variant's: it holds its
        own row, which the module on board does not use (it counts its whole demand)."""
        held = self.standing_by.copy()
        if self.fallback_variant is not None:
            held &= ~self.fallback_variant
        return freeze(held)

    def node_index(self, name: str) -> int:
        for j, node in enumerate(self.nodes):
            if name in (node.name, node.node_name):
                return j
        raise KeyError(name)

    def label(self, i: int) -> str:
        inst = self.instances[i]
        return f"{inst.robot}/{inst.module}" if inst.robot else f"{inst.module}#{inst.replica}"
