"""What one module gets on one node: may it run there (the gene space of
multi-robot-edge-cloud-scheduling III-E), its transfer time (eq. 4), its CPU and execution
time under the limits and nominal allocations (IV-B, Fig. 3) and its degradation ladder.

``build_problem`` asks for these per (instance, node). Every robot's copy of a module sees the
edge and cloud nodes alike when the robots' uplinks are alike, so ``PairTable.block``
evaluates a module once per (cycle, pool tier, robot uplink) over all edge and cloud nodes and
the build copies that row into each instance: a thousand robots cost a handful of blocks
instead of a million Python-level pair evaluations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.base import parse_cpu, parse_millis, parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule, auto_profiled

from . import dnnpairs
from .network import LOCAL, Link, path
from .problem import EXEC_SHARE_OF_CYCLE
from .rows import Learnt, ProfileRow, carry_noise
from .taxonomy import may_degrade, must_stay_onboard

__all__ = ["Block", "Pair", "PairTable", "Refusal", "pad_rungs", "profile_rows", "rows_for"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Pair:
    """One module on one node it may run on."""

    net_mean: float
    net_std: float
    bits: float  # traffic with the robot when off board, bit/s
    pick: ProfileRow  # the limits allocation's CPU and execution time
    top: ProfileRow  # the nominal allocation's (the largest profiled parallelism)
    rungs: tuple[ProfileRow, ...]  # pick, then the smaller profiled CPUs (may degrade), or ()
    action: int = -1  # a split network's action here (contract.dnnsplit); -1: not one


class Refusal(str):
    """Why a module may not run on a node, in words, and the rule that says so (``rule``:
    taxonomy, tier, device, gpu, realtimeKernel, privacy, profile, dnn). A ``str``, so the build
    joins refusals into its messages as before; ``fogfleet explain`` reads ``rule``."""

    rule: str

    def __new__(cls, text: str, rule: str) -> Refusal:
        out = super().__new__(cls, text)
        out.rule = rule
        return out


@dataclass(frozen=True)
class Block:
    """One module on a run of nodes (arrays aligned with them; rungs padded to ``k``)."""

    allowed: NDArray[np.bool_]
    net_mean: F64
    net_std: F64
    lim: tuple[F64, F64, F64]  # cpu, mean, std of the limits pick (m,) each
    nom: tuple[F64, F64, F64, F64]  # request, use, mean, std of the nominal allocation
    rungs: tuple[F64, F64, F64]  # (m, k) cpu, mean, std: rung 0 the pick, then smaller
    depth: NDArray[np.int64]  # (m,) rungs below the pick
    why: tuple[str, ...]
    bits: float
    action: NDArray[np.int64] | None = None  # (m,) a split network's action per node (-1: none)

    @property
    def any_allowed(self) -> bool:
        """Whether the module may run on any node of the run."""
        return bool(self.allowed.any())


def profile_rows(module: SoftwareModule, node: ComputeNode) -> list[ProfileRow]:
    """Fig. 3 rows for this node's hardware type; 'default' rows scaled by speedFactor."""
    return rows_for(module, node.spec.hardware_type, parse_quantity(node.spec.speed_factor))


def rows_for(module: SoftwareModule, hardware_type: str, speed_factor: float) -> list[ProfileRow]:
    """The module's rows on hardware ``hardware_type`` (Fig. 3): its own rows as declared, or
    else the 'default' rows with every time divided by the node's ``speed_factor``.

    The one place that decides which row a module runs with on a node: the planner's pairs and
    the rendered pod (``render.ros``) both ask here, so a pod plays the rows it was planned
    with. A split network (``spec.dnn``) has no rows of its own: its pods run the real network
    (``workload.dnn``, which ignores rows); these are the whole network's time at each CPU step
    (``dnnpairs.dnn_rows``), what its status reports as declared."""
    if module.spec.dnn is not None:
        full = dnnpairs.full_seconds(
            module.spec.dnn, dnnpairs.NodeKind(hardware_type, speed_factor)
        )
        return [] if full is None else dnnpairs.dnn_rows(full, math.inf)
    own = [r for r in module.spec.profile if r.hardware_type == hardware_type]
    scale = 1.0
    if not own:
        own = [r for r in module.spec.profile if r.hardware_type == "default"]
        scale = 1.0 / max(speed_factor, 1e-6)
    rows = [
        ProfileRow(
            parse_cpu(r.cpu),
            parse_millis(r.mean_millis) * scale,
            parse_millis(r.std_millis) * scale,
        )
        for r in own
    ]
    return sorted(rows, key=lambda r: r.cpu)


def transfer(module: SoftwareModule, link: Link) -> tuple[float, float, float]:
    """t_in + t_out for one cycle over ``link`` (mean, std) and the traffic in bit/s (eq. 4)."""
    topics = module.spec.topics
    t = 0.0
    traffic = 0.0
    for group in (topics.subscribes, topics.publishes):
        if not group:
            continue
        bits = sum(parse_quantity(tp.size_bytes) * 8 for tp in group)
        t += link.latency + bits / link.bandwidth
        traffic += sum(
            parse_quantity(tp.size_bytes) * 8 * parse_quantity(tp.rate_hz) for tp in group
        )
    n_dirs = int(bool(topics.subscribes)) + int(bool(topics.publishes))
    std = link.jitter * math.sqrt(n_dirs)
    # lost packets are resent after roughly one round trip
    t += link.loss * 2 * link.latency * n_dirs
    return t, std, traffic


def pad_rungs(rungs: Sequence[ProfileRow], k: int) -> list[tuple[float, float, float]]:
    """``rungs`` as (cpu, mean, std), padded to ``k`` with the last (smallest) one."""
    out = [(r.cpu, r.mean, r.std) for r in rungs]
    return out + [out[-1]] * (k - len(out))


class PairTable:
    """Pair evaluations of one build (memoised profiles, transfers and blocks)."""

    def __init__(
        self,
        nodes: Sequence[ComputeNode],
        caps: F64,
        links: Sequence[Link],
        corrections: Mapping[tuple[str, str], Learnt] | None = None,
    ) -> None:
        self.nodes = nodes
        self.caps = caps
        self.links = links
        # (module, hardware type) -> the correction of the declared rows (domain.observed),
        # with a module's noise on the types where its own is not known (rows.carry_noise)
        types = (nd.spec.hardware_type for nd in nodes)
        self.corrections = carry_noise(corrections or {}, types)
        self._profiles: dict[tuple[int, str, Any], list[ProfileRow]] = {}
        self._transfers: dict[tuple[int, Link], tuple[float, float, float]] = {}
        self._blocks: dict[tuple[Any, ...], Block] = {}

    def pair(
        self,
        mod: SoftwareModule,
        cycle: float,
        pool_tier: Tier | None,
        j: int,
        home: int,
        home_link: Link,
        home_kind: dnnpairs.NodeKind = dnnpairs.REFERENCE,
        alone: bool = False,
    ) -> Pair | Refusal | None:
        """Module ``mod`` (instance of robot ``home``, -1 for a shared replica) on node ``j``:
        a Pair, or why it may not run there (None: not worth saying, such as another robot's
        computer or a node of another pool's tier). ``home_kind`` is the robot's hardware type
        and speed (a split network's head runs there); ``alone``: no edge or cloud node
        is left to the instance (a split network's local model then answers at home)."""
        nd = self.nodes[j]
        ns = nd.spec
        spec = mod.spec
        req = spec.requirements
        name = nd.metadata.name
        if ns.tier is Tier.ROBOT and j != home:
            return None  # never another robot's computer (III-E); shared replicas never on robots
        if must_stay_onboard(spec.taxonomy) and j != home:
            return Refusal(
                f"{name}: module is hard real-time or safety-critical, so it stays on its robot",
                "taxonomy",
            )
        if req.tiers and ns.tier not in req.tiers:
            return Refusal(f"{name}: tier {ns.tier.value} not in requirements.tiers", "tier")
        if pool_tier is not None and ns.tier is not pool_tier:
            return None  # a replica counted for another tier's pool
        have = {d.type for d in ns.devices}
        missing = [d.value for d in req.devices if d not in have]
        if missing:
            return Refusal(f"{name}: lacks device {', '.join(missing)}", "device")
        if req.gpu and self.caps[j, 2] < 1:
            return Refusal(f"{name}: no GPU", "gpu")
        if req.realtime_kernel and not ns.realtime_kernel:
            return Refusal(f"{name}: no real-time kernel", "realtimeKernel")
        if ns.privacy < req.min_privacy:
            return Refusal(
                f"{name}: privacy level {ns.privacy} < required {req.min_privacy}", "privacy"
            )
        if spec.dnn is not None:
            return self._dnn_pair(mod, cycle, j, home, home_link, home_kind, alone)
        key = (id(mod), ns.hardware_type, ns.speed_factor)
        if key not in self._profiles:
            rows = profile_rows(mod, nd)
            learnt = self.corrections.get((mod.metadata.name, ns.hardware_type))
            if learnt is not None:  # learnt from what ran (issue 10)
                rows = [learnt.row(r) for r in rows]
            self._profiles[key] = rows
        rows = [r for r in self._profiles[key] if r.cpu <= self.caps[j, 0] + 1e-9]
        if not rows:
            auto = " (profiling.mode auto: the operator profiles it there first)"
            return Refusal(
                f"{name}: no execution-time profile for hardware type "
                f"{ns.hardware_type!r} that fits its CPU" + (auto if auto_profiled(spec) else ""),
                "profile",
            )
        link = LOCAL if j == home else path(home_link, self.links[j])
        if (id(mod), link) not in self._transfers:
            self._transfers[id(mod), link] = transfer(mod, link)
        t, s, bits = self._transfers[id(mod), link]
        # limits: the smallest CPU whose mean + 2 std fits the cycle's share, else the fastest
        budget = EXEC_SHARE_OF_CYCLE * cycle - t
        fit = [r for r in rows if r.mean + 2 * r.std <= budget]
        pick = fit[0] if fit else min(rows, key=lambda r: (r.mean, r.cpu))
        rungs: tuple[ProfileRow, ...] = ()
        if may_degrade(spec.taxonomy):
            smaller = sorted((r for r in rows if r.cpu < pick.cpu), key=lambda r: -r.cpu)
            rungs = (pick, *smaller)
        # nominal: request as declared, no limit, uses the largest profiled parallelism
        return Pair(t, s, bits, pick, rows[-1], rungs)

    def _dnn_pair(
        self,
        mod: SoftwareModule,
        cycle: float,
        j: int,
        home: int,
        home_link: Link,
        home_kind: dnnpairs.NodeKind,
        alone: bool,
    ) -> Pair | Refusal:
        """A split network on node ``j`` (``domain.dnnpairs``): its local model at home, its
        tail elsewhere, with the CPU step whose frame fits alpha's share (as ``pair`` does)."""
        nd = self.nodes[j]
        name = nd.metadata.name
        assert mod.spec.dnn is not None
        alpha = dnnpairs.alpha_s(mod.spec.dnn, cycle)
        if j == home:
            got = dnnpairs.local_pair_rows(mod, cycle, home_kind, self.caps[j, 0], alone)
            if isinstance(got, str):
                return Refusal(f"{name}: {got}", _dnn_rule(got))
            rows, outside, std, bits = got, 0.0, 0.0, 0.0
            action = len(mod.spec.dnn.split_points) + 1  # the local model (eq. 2's n+1)
        else:
            link = path(home_link, self.links[j])
            tail = dnnpairs.off_board(mod, cycle, home_kind, dnnpairs.kind_of(nd), link)
            if isinstance(tail, str):
                return Refusal(f"{name}: {tail}", _dnn_rule(tail))
            on, choice, outside, std, bits = tail
            rows = dnnpairs.tail_rows(on, choice.action, self.caps[j, 0])
            action = choice.action.index
        if not rows:
            return Refusal(f"{name}: has less than {dnnpairs.CPU_STEPS[0]:g} core", "profile")
        fit = [r for r in rows if r.mean <= EXEC_SHARE_OF_CYCLE * alpha - outside]
        pick = fit[0] if fit else rows[-1]
        rungs: tuple[ProfileRow, ...] = ()
        if may_degrade(mod.spec.taxonomy):
            rungs = (pick, *sorted((r for r in rows if r.cpu < pick.cpu), key=lambda r: -r.cpu))
        return Pair(outside, std, bits, pick, rows[-1], rungs, action)

    def robot_kind(self, j: int) -> dnnpairs.NodeKind:
        """Node ``j``'s hardware type and speed (a split network's head runs on its robot)."""
        return dnnpairs.kind_of(self.nodes[j])

    def block(
        self,
        mod: SoftwareModule,
        cycle: float,
        pool_tier: Tier | None,
        cols: range,
        home_link: Link,
        home_kind: dnnpairs.NodeKind = dnnpairs.REFERENCE,
    ) -> Block:
        """``pair`` over the nodes ``cols`` (none of them the instance's own robot), memoised
        per (module, cycle, pool tier, nodes, the robot's uplink and, for a split network, the
        robot's speed)."""
        kind = home_kind if mod.spec.dnn is not None else dnnpairs.REFERENCE
        key = (id(mod), cycle, pool_tier, cols.start, cols.stop, home_link, kind)
        hit = self._blocks.get(key)
        if hit is not None:
            return hit
        m = len(cols)
        pairs = [self.pair(mod, cycle, pool_tier, j, -2, home_link, kind) for j in cols]
        ok = [isinstance(p, Pair) for p in pairs]
        got = [p for p in pairs if isinstance(p, Pair)]
        k = max((len(p.rungs) for p in got), default=1) or 1
        lim = np.zeros((m, 3))
        lim[:, 1] = np.inf
        nom = np.zeros((m, 4))
        nom[:, 2] = np.inf
        net = np.zeros((m, 2))
        rungs = np.zeros((m, k, 3))
        rungs[:, :, 1] = np.inf
        depth = np.zeros(m, dtype=np.int64)
        nominal_cpu = parse_cpu(mod.spec.resources.cpu)
        for r, p in enumerate(pairs):
            if not isinstance(p, Pair):
                continue
            net[r] = p.net_mean, p.net_std
            lim[r] = p.pick.cpu, p.pick.mean, p.pick.std
            nom[r] = nominal_cpu, p.top.cpu, p.top.mean, p.top.std
            rungs[r] = pad_rungs(p.rungs or (p.pick,), k)
            depth[r] = max(len(p.rungs) - 1, 0)
        blk = Block(
            allowed=np.array(ok, dtype=bool),
            net_mean=net[:, 0],
            net_std=net[:, 1],
            lim=(lim[:, 0].copy(), lim[:, 1].copy(), lim[:, 2].copy()),
            nom=tuple(nom[:, c].copy() for c in range(4)),  # type: ignore[arg-type]
            rungs=tuple(np.ascontiguousarray(rungs[:, :, c]) for c in range(3)),  # type: ignore[arg-type]
            depth=depth,
            why=tuple(p for p in pairs if isinstance(p, str)),
            bits=got[0].bits if got else 0.0,
            action=np.array([p.action if isinstance(p, Pair) else -1 for p in pairs])
            if mod.spec.dnn is not None
            else None,
        )
        self._blocks[key] = blk
        return blk


def _dnn_rule(why: str) -> str:
    """The rule a split network's refusal names: ``profile`` while its times on a hardware
    type are not known yet (``dnnpairs.network_on``), else ``dnn``."""
    return "profile" if why.startswith("no times of its network") else "dnn"
