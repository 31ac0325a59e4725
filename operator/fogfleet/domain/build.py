"""``build_problem``: a fleet, its catalogue (modules, ComputeNodes) and the current placement
into the immutable ``Problem`` (the gene spaces of multi-robot-edge-cloud-scheduling III-E, the
allocations of IV-B, eq. 4's transfer times per instance and node)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.base import parse_cpu, parse_memory, parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.dnn import Dnn
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import Scope, SoftwareModule
from fogfleet.errors import InvalidSpec

from .checks import capacity_of, module_cycle
from .dnnpairs import REFERENCE
from .fallback import standbys
from .network import Link, uplink
from .pairs import Block, Pair, PairTable, Refusal, pad_rungs
from .problem import (
    TIER_CODE,
    Allocation,
    Instance,
    Ladder,
    LazyLadder,
    NodeInfo,
    Problem,
    freeze,
)
from .references import named_module, resolve_nodes
from .rows import Learnt, ProfileRow
from .taxonomy import module_priority

__all__ = ["build_problem", "refusals"]

F64 = NDArray[np.float64]


def _pool_tiers(
    pool: Mapping[str, int] | None, replicas: int, running: Mapping[int, Tier] | None = None
) -> list[Tier | None]:
    """One entry per replica: the tier whose pool it belongs to (None: any allowed tier).

    The key ``any`` counts replicas that may run on any allowed tier. ``running[r]`` is the
    tier replica ``r`` runs on now: it keeps that tier while the pool there has room, so
    growing the edge pool adds an edge replica instead of moving a serving cloud one. The
    slots left are filled edge first."""
    if not pool:
        return [None] * replicas
    slots = {t: max(int(pool.get(t.value, 0)), 0) for t in (Tier.EDGE, Tier.CLOUD)}
    total = sum(slots.values()) + max(int(pool.get("any", 0)), 0)
    out: list[Tier | None] = [None] * total
    free = [True] * total
    for r, tier in sorted((running or {}).items()):
        if r < total and tier in slots and slots[tier] > 0:
            out[r], free[r] = tier, False
            slots[tier] -= 1
    fill = [t for t in (Tier.EDGE, Tier.CLOUD) for _ in range(slots[t])]
    for r in range(total):
        if free[r] and fill:
            out[r] = fill.pop(0)
    return out


class _Resolved(NamedTuple):
    """One of the fleet's modules with its overrides applied."""

    module: SoftwareModule
    cycle: float  # seconds
    activation: float  # share of time active, 0-1
    replicas: int


@dataclass(frozen=True)
class _Wants:
    """What the fleet's modules ask for beyond their resources, by module name."""

    tiers: dict[str, list[Tier]]  # preferred tiers (override, module, fleet)
    priority: dict[str, int]  # priority (override, module, taxonomy)


@dataclass(frozen=True)
class _Instances:
    """The instances to place, aligned: each one's module, home robot (-1: shared) and the
    tier of the pool it counts in (None: any allowed tier)."""

    instances: list[Instance]
    module: list[_Resolved]
    home: list[int]
    pool_tier: list[Tier | None]


@dataclass
class _Grid:
    """Per (instance, node): may it run there, its transfer time and, for the limits and
    nominal allocations, its CPU and execution time; per instance its off-board traffic and
    why it fits nowhere; the blocks and home rungs the degradation ladder is built from."""

    allowed: NDArray[np.bool_]
    net_mean: F64
    net_std: F64
    traffic: F64
    lim: tuple[F64, F64, F64]  # the limits pick's cpu, mean, std
    nom: tuple[F64, F64, F64, F64]  # the nominal allocation's request, use, mean, std
    reasons: dict[int, str] = field(default_factory=dict)
    blocks: list[Block] = field(default_factory=list)
    home_rungs: dict[int, tuple[ProfileRow, ...]] = field(default_factory=dict)
    dnn_action: NDArray[np.int64] | None = None  # (I, N) a split network's action, -1: none

    def split_actions(self) -> NDArray[np.int64]:
        """``dnn_action``, made on first use (a fleet without split networks has none)."""
        if self.dnn_action is None:
            self.dnn_action = np.full(self.allowed.shape, -1, dtype=np.int64)
        return self.dnn_action

    @classmethod
    def empty(cls, i_count: int, n: int) -> _Grid:
        def zeros() -> F64:
            return np.zeros((i_count, n))

        def inf() -> F64:
            return np.full((i_count, n), np.inf)

        return cls(
            allowed=np.zeros((i_count, n), dtype=bool),
            net_mean=zeros(),
            net_std=zeros(),
            traffic=np.zeros(i_count),
            lim=(zeros(), inf(), zeros()),
            nom=(zeros(), zeros(), inf(), zeros()),
        )


def build_problem(
    fleet: RobotFleet,
    catalog: Catalog,
    current: dict[tuple[str, str, int], str] | None = None,
    pools: Mapping[str, Mapping[str, int]] | None = None,
    measured_links: Mapping[str, Link] | None = None,
    corrections: Mapping[tuple[str, str], Learnt] | None = None,
) -> Problem:
    """Resolve a fleet against the catalog into a Problem.

    ``current`` maps (robot, module, replica) to the node it runs on now. ``pools`` gives the
    autoscaler's decision for shared modules: module name -> {tier: replicas} (tier ``any``:
    replicas without a pool); replica ``r`` of
    such a module may then only run on nodes of the tier it was counted for (edge replicas
    first, then cloud), which is how privacy-constrained pools stay on the edge.
    ``measured_links`` replaces the declared uplink of the ComputeNodes it names (a robot's
    link measured worse than declared, ``domain.linkhealth``). ``corrections`` corrects the
    declared profile rows of a (module, hardware type) (learnt from what ran: a factor and the
    cycle's noise, ``domain.observed``)."""
    namespace = fleet.metadata.namespace or "default"
    robots, others = resolve_nodes(fleet, catalog)
    nodes = robots + others
    caps = np.array([capacity_of(nd) for nd in nodes], dtype=np.float64)
    measured = measured_links or {}
    links = [measured.get(nd.metadata.name) or uplink(nd.spec) for nd in nodes]
    modules, wants = _resolve_modules(fleet, catalog, namespace)
    inst = _expand_instances(modules, robots, nodes, current, pools)
    grid = _fill_grid(inst, PairTable(nodes, caps, links, corrections), links, len(robots))
    held = standbys(
        fleet,
        catalog,
        modules,
        inst.instances,
        inst.home,
        robots,
        grid.allowed,
        grid.lim,
        grid.home_rungs,
    )
    remote = range(len(robots), len(nodes))
    lim_req, lim_exe, lim_std = grid.lim
    nom_req, nom_use, nom_exe, nom_std = grid.nom
    return Problem(
        fallback=held.keep,
        fallback_row=held.row,
        fallback_variant=held.variant,
        fallback_cycle=held.cycle,
        fallback_need=held.need,
        preferred=_preferred(nodes, inst.instances, wants.tiers),
        priority=freeze(
            np.array([wants.priority[i.module] for i in inst.instances], dtype=np.int64)
        ),
        ladder_source=_lazy_ladder(grid.blocks, inst.home, grid.home_rungs, remote, grid.lim),
        fleet=fleet.metadata.name,
        namespace=namespace,
        nodes=tuple(_node_info(nd) for nd in nodes),
        instances=tuple(inst.instances),
        tier=freeze(np.array([TIER_CODE[nd.spec.tier] for nd in nodes], dtype=np.int64)),
        capacity=freeze(caps),
        cost=freeze(np.array([parse_quantity(nd.spec.cost_per_core_hour) for nd in nodes])),
        power=freeze(_power(nodes)),
        uplink_bandwidth=freeze(np.array([lk.bandwidth for lk in links])),
        home=freeze(np.array(inst.home, dtype=np.int64)),
        allowed=freeze(grid.allowed),
        activation=freeze(np.array([m.activation for m in inst.module])),
        cycle=freeze(np.array([m.cycle for m in inst.module])),
        memory=freeze(_per_instance(inst, lambda m: parse_memory(m.spec.resources.memory))),
        gpu=freeze(_per_instance(inst, lambda m: float(m.spec.resources.gpu))),
        net_mean=freeze(grid.net_mean),
        net_std=freeze(grid.net_std),
        traffic=freeze(grid.traffic),
        limits=Allocation(freeze(lim_req), lim_req, freeze(lim_exe), freeze(lim_std), True),
        nominal=Allocation(
            freeze(nom_req), freeze(nom_use), freeze(nom_exe), freeze(nom_std), False
        ),
        current=freeze(_current_nodes(nodes, inst.instances, current, grid.allowed)),
        reasons=grid.reasons,
        dnn_action=None if grid.dnn_action is None else freeze(grid.dnn_action),
        split_models=_split_models(modules),
        uplink_latency=freeze(np.array([lk.latency for lk in links])),
    )


def _split_models(modules: list[_Resolved]) -> dict[str, Dnn] | None:
    """The split networks among the fleet's modules (``domain.dnnpairs.network_on`` resolves
    them per robot and tail node)."""
    out = {m.module.metadata.name: m.module.spec.dnn for m in modules if m.module.spec.dnn}
    return out or None


def refusals(
    fleet: RobotFleet,
    catalog: Catalog,
    instance: Instance,
    current: Mapping[tuple[str, str, int], str] | None = None,
    pools: Mapping[str, Mapping[str, int]] | None = None,
    corrections: Mapping[tuple[str, str], Learnt] | None = None,
) -> dict[int, Refusal | None]:
    """Why ``instance`` may not run on each node (by index, as ``build_problem`` orders them)
    whose gene space it is not in: ``PairTable.pair``'s own answer, the one the build asked.
    None: not a node it could use (another robot's computer, another pool's tier); a node it
    may use is absent. Called with what ``build_problem`` was called with."""
    namespace = fleet.metadata.namespace or "default"
    robots, others = resolve_nodes(fleet, catalog)
    nodes = robots + others
    modules, _ = _resolve_modules(fleet, catalog, namespace)
    resolved = next(m for m in modules if m.module.metadata.name == instance.module)
    caps = np.array([capacity_of(nd) for nd in nodes], dtype=np.float64)
    links = [uplink(nd.spec) for nd in nodes]  # the refusals come before the transfer time
    table = PairTable(nodes, caps, links, corrections)
    names = [nd.metadata.name for nd in robots]
    home = names.index(instance.robot) if instance.robot else -1
    tier: Tier | None = None
    if home < 0:
        inst = _expand_instances([resolved], robots, nodes, current, pools)
        tier = inst.pool_tier[instance.replica] if instance.replica < len(inst.pool_tier) else None
    link = links[home] if home >= 0 else _mean_link(links[: len(robots)])
    kind = table.robot_kind(home) if home >= 0 else REFERENCE

    def pair(j: int, alone: bool = False) -> Pair | Refusal | None:
        return table.pair(resolved.module, resolved.cycle, tier, j, home, link, kind, alone)

    # a split network's local model answers alone at home when no edge or cloud node is left
    alone = resolved.module.spec.dnn is not None and not any(
        isinstance(pair(j), Pair) for j in range(len(robots), len(nodes))
    )
    out: dict[int, Refusal | None] = {}
    for j in range(len(nodes)):
        got = pair(j, alone)
        if not isinstance(got, Pair):
            out[j] = got
    return out


def _resolve_modules(
    fleet: RobotFleet, catalog: Catalog, namespace: str
) -> tuple[list[_Resolved], _Wants]:
    """The fleet's modules with their overrides applied, and what each asks for."""
    modules: list[_Resolved] = []
    wants = _Wants({}, {})
    for k, ref in enumerate(fleet.spec.modules):
        mod = named_module(fleet, catalog, namespace, k, ref)
        if isinstance(mod, InvalidSpec):
            raise mod
        ov = ref.overrides
        cycle = module_cycle(fleet, k, ref, mod)
        if isinstance(cycle, InvalidSpec):
            raise cycle
        act = (ov.activation_percent or mod.spec.activation_percent) / 100.0
        modules.append(_Resolved(mod, cycle, act, ov.replicas or mod.spec.replicas))
        name = mod.metadata.name
        wants.priority[name] = ov.priority if ov.priority is not None else module_priority(mod.spec)
        if ov.preferred_tiers is not None:
            wants.tiers[name] = ov.preferred_tiers
        else:
            wants.tiers[name] = mod.spec.preferred_tiers or fleet.spec.preferred_tiers
    return modules, wants


def _expand_instances(
    modules: list[_Resolved],
    robots: list[ComputeNode],
    nodes: list[ComputeNode],
    current: Mapping[tuple[str, str, int], str] | None,
    pools: Mapping[str, Mapping[str, int]] | None,
) -> _Instances:
    """One instance per robot of a per-robot module, one per replica of a shared one (its
    replicas counted into the autoscaler's pools, ``_pool_tiers``)."""
    robot_index = {nd.metadata.name: j for j, nd in enumerate(robots)}
    node_tier: dict[str, Tier] = {}
    for nd in nodes:
        node_tier[nd.metadata.name] = node_tier[nd.node_name] = nd.spec.tier
    out = _Instances([], [], [], [])

    def add(instance: Instance, resolved: _Resolved, home: int, tier: Tier | None) -> None:
        out.instances.append(instance)
        out.module.append(resolved)
        out.home.append(home)
        out.pool_tier.append(tier)

    for resolved in modules:
        mod = resolved.module
        if mod.spec.scope is Scope.PER_ROBOT:
            for robot in robots:
                name = robot.metadata.name
                add(Instance(name, mod.metadata.name, 0), resolved, robot_index[name], None)
        else:
            running = {
                r: node_tier[n]
                for (robot, m, r), n in (current or {}).items()
                if not robot and m == mod.metadata.name and n in node_tier
            }
            pool = pools.get(mod.metadata.name) if pools else None
            for r, tier in enumerate(_pool_tiers(pool, resolved.replicas, running)):
                add(Instance("", mod.metadata.name, r), resolved, -1, tier)
    return out


def _mean_link(links: list[Link]) -> Link:
    """The mean of the robots' uplinks: what shared replicas, which talk to the whole fleet,
    are planned with."""
    return Link(
        latency=float(np.mean([lk.latency for lk in links])),
        jitter=float(np.mean([lk.jitter for lk in links])),
        bandwidth=float(np.mean([lk.bandwidth for lk in links])),
        loss=float(np.mean([lk.loss for lk in links])),
    )


def _fill_grid(inst: _Instances, table: PairTable, links: list[Link], n_robots: int) -> _Grid:
    """Each instance's pair with its home robot, then its block over every edge and cloud
    node (one block per module and link, ``PairTable.block``)."""
    n = len(links)
    grid = _Grid.empty(len(inst.instances), n)
    mean_robot = _mean_link(links[:n_robots])
    remote = range(n_robots, n)  # edge and cloud nodes: one block per module and link
    sharing: dict[int, tuple[Block, list[int]]] = {}  # id(block) -> the block, its instances
    for i, (instance, resolved, h) in enumerate(
        zip(inst.instances, inst.module, inst.home, strict=True)
    ):
        mod, cycle, tier = resolved.module, resolved.cycle, inst.pool_tier[i]
        why: list[str] = []
        at_home = False
        kind = table.robot_kind(h) if h >= 0 else REFERENCE
        blk = table.block(mod, cycle, tier, remote, links[h] if h >= 0 else mean_robot, kind)
        if h >= 0:
            own = table.pair(mod, cycle, tier, h, h, links[h], kind, not blk.any_allowed)
            if isinstance(own, Pair):
                _set_home_pair(grid, i, h, own, parse_cpu(mod.spec.resources.cpu))
                at_home = True
            elif own is not None:
                why.append(own)
        grid.blocks.append(blk)
        sharing.setdefault(id(blk), (blk, []))[1].append(i)
        why += blk.why
        if not at_home and not blk.any_allowed:
            where = "; ".join(why) if why else "no node in the fleet can host it"
            who = f"{instance.robot + '/' if instance.robot else ''}{instance.module}"
            grid.reasons[i] = f"{who} fits nowhere: {where}"
    for blk, rows in sharing.values():
        _set_block(grid, np.asarray(rows), remote.start, blk)
    return grid


def _set_home_pair(grid: _Grid, i: int, h: int, own: Pair, nominal_request: float) -> None:
    """Instance ``i`` may run on its robot ``h``: what it gets there."""
    grid.allowed[i, h] = True
    grid.net_mean[i, h], grid.net_std[i, h] = own.net_mean, own.net_std
    for arr, v in zip(grid.lim, (own.pick.cpu, own.pick.mean, own.pick.std), strict=True):
        arr[i, h] = v
    nominal = (nominal_request, own.top.cpu, own.top.mean, own.top.std)
    for arr, v in zip(grid.nom, nominal, strict=True):
        arr[i, h] = v
    if own.rungs:
        grid.home_rungs[i] = own.rungs
    if own.action >= 0:
        grid.split_actions()[i, h] = own.action


def _set_block(grid: _Grid, rows: NDArray[np.int64], start: int, blk: Block) -> None:
    """The rows over the edge and cloud nodes (columns ``start:``) of the instances ``rows``,
    which share ``blk``: one broadcast write per array, not one per instance."""
    grid.allowed[rows, start:] = blk.allowed
    grid.net_mean[rows, start:] = blk.net_mean
    grid.net_std[rows, start:] = blk.net_std
    for arr, row in zip((*grid.lim, *grid.nom), (*blk.lim, *blk.nom), strict=True):
        arr[rows, start:] = row
    if blk.any_allowed:
        grid.traffic[rows] = blk.bits
    if blk.action is not None:
        grid.split_actions()[rows, start:] = blk.action


def _current_nodes(
    nodes: list[ComputeNode],
    instances: list[Instance],
    current: Mapping[tuple[str, str, int], str] | None,
    allowed: NDArray[np.bool_],
) -> NDArray[np.int64]:
    """The node each instance runs on now (by ComputeNode or Node name), -1 where none or
    where it may not run any more."""
    cur = np.full(len(instances), -1, dtype=np.int64)
    if not current:
        return cur
    by_name: dict[str, list[int]] = {}
    for j, nd in enumerate(nodes):
        for key in dict.fromkeys((nd.metadata.name, nd.node_name)):
            by_name.setdefault(key, []).append(j)
    for i, inst in enumerate(instances):
        node_name = current.get((inst.robot, inst.module, inst.replica))
        for j in by_name.get(node_name, []) if node_name is not None else []:
            if allowed[i, j]:
                cur[i] = j
    return cur


def _power(nodes: list[ComputeNode]) -> F64:
    """Per node: battery Wh, idle W, W per core, W per Mbps of radio (0 where undeclared)."""
    power = np.zeros((len(nodes), 4))
    for j, nd in enumerate(nodes):
        p = nd.spec.power
        if p is not None:
            power[j] = [
                parse_quantity(p.battery_watt_hours),
                parse_quantity(p.idle_watts),
                parse_quantity(p.per_core_watts),
                parse_quantity(p.radio_watts_per_mbps),
            ]
    return power


def _per_instance(inst: _Instances, value: Callable[[SoftwareModule], float]) -> F64:
    """A module's ``value`` for each instance of it."""
    if not inst.module:
        return np.zeros(0)
    return np.array([value(m.module) for m in inst.module])


def _preferred(
    nodes: list[ComputeNode], instances: list[Instance], wishes: Mapping[str, list[Tier]]
) -> NDArray[np.bool_] | None:
    """(I, N): is the node in a tier the instance's module prefers (every node where it
    states no preference); None when no module states one."""
    if not any(wishes.values()):
        return None
    tiers = [nd.spec.tier for nd in nodes]
    names = list(dict.fromkeys(inst.module for inst in instances))
    by_module = np.array(
        [[not wishes[m] or t in wishes[m] for t in tiers] for m in names], dtype=bool
    ).reshape(len(names), len(nodes))
    which = {m: k for k, m in enumerate(names)}
    rows = np.array([which[inst.module] for inst in instances], dtype=np.int64)
    return freeze(by_module[rows].reshape(len(instances), len(nodes)))


def _node_info(nd: ComputeNode) -> NodeInfo:
    return NodeInfo(
        nd.metadata.name,
        nd.node_name,
        nd.spec.tier,
        nd.spec.hardware_type,
        parse_quantity(nd.spec.speed_factor),
    )


Rungs = tuple[tuple[F64, F64, F64], NDArray[np.int64]]  # a block's (m, k) rungs, (m,) depth


def _lazy_ladder(
    blocks: list[Block],
    home: list[int],
    home_rungs: Mapping[int, tuple[ProfileRow, ...]],
    remote: range,
    lim: tuple[F64, F64, F64],
) -> LazyLadder | None:
    """The ladder, to be built on first use (``LazyLadder``); None where nothing may degrade.
    It keeps only the blocks' rungs (one per distinct block) and the limits arrays."""
    parts: list[Rungs] = [(blk.rungs, blk.depth) for blk in blocks]
    if not any(d.any() for _, d in parts) and not any(len(r) > 1 for r in home_rungs.values()):
        return None
    rows = dict(home_rungs)
    digest = hashlib.sha256()
    which: dict[int, int] = {}  # distinct blocks in order of first use
    for rungs, d in parts:
        if id(rungs) not in which:
            which[id(rungs)] = len(which)
            for a in (*rungs, d):
                digest.update(np.ascontiguousarray(a).tobytes())
    digest.update(np.array([which[id(r)] for r, _ in parts], dtype=np.int64).tobytes())
    digest.update(repr(sorted((i, tuple(r)) for i, r in rows.items())).encode())
    return LazyLadder(lambda: _ladder(parts, home, rows, remote, lim), digest.digest())


def _ladder(
    parts: list[Rungs],
    home: list[int],
    home_rungs: Mapping[int, tuple[ProfileRow, ...]],
    remote: range,
    lim: tuple[F64, F64, F64],
) -> Ladder | None:
    """Rung 0 is the limits pick everywhere; deeper rungs only where a module may degrade and
    its profile has smaller CPU rows for that node (padded with the smallest)."""
    depth = np.zeros(lim[0].shape, dtype=np.int64)
    for i, (_, d) in enumerate(parts):
        depth[i, remote.start :] = d
    for i, rows in home_rungs.items():
        depth[i, home[i]] = len(rows) - 1
    if not depth.any():
        return None
    k = int(depth.max()) + 1
    out = []
    for c in range(3):
        lad = np.empty((*lim[c].shape, k))
        lad[:] = lim[c][:, :, None]  # rung 0 (and every rung where nothing degrades)
        padded: dict[int, F64] = {}  # per block (instances of one block share its rungs)
        for i, (rungs, d) in enumerate(parts):
            if not d.any():
                continue
            got = padded.get(id(rungs))
            if got is None:
                r = rungs[c]
                got = np.concatenate([r, np.repeat(r[:, -1:], k - r.shape[1], axis=1)], axis=1)
                padded[id(rungs)] = got
            lad[i, remote.start :] = got
        for i, rows in home_rungs.items():
            lad[i, home[i]] = [v[c] for v in pad_rungs(rows, k)]
        out.append(freeze(lad))
    return Ladder(out[0], out[1], out[2], freeze(depth))
