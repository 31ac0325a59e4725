"""``build_problem``: a fleet, its catalogue (modules, ComputeNodes) and the current placement
into the immutable ``Problem`` (the gene spaces of multi-robot-edge-cloud-scheduling III-E, the
allocations of IV-B, eq. 4's transfer times per instance and node)."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.base import parse_cpu, parse_memory, parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import Scope, SoftwareModule
from fogfleet.errors import DanglingReference, InvalidSpec

from .fallback import standbys
from .network import Link, uplink
from .pairs import Block, Pair, PairTable, pad_rungs
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
from .rows import Learnt, ProfileRow
from .taxonomy import module_priority

__all__ = ["build_problem", "resolve_nodes"]

F64 = NDArray[np.float64]


def resolve_nodes(
    fleet: RobotFleet, catalog: Catalog
) -> tuple[list[ComputeNode], list[ComputeNode]]:
    """The fleet's robots and its other nodes (named, then selected), or why not."""
    obj = f"RobotFleet/{fleet.metadata.name}"
    robots: list[ComputeNode] = []
    for k, name in enumerate(fleet.spec.robots):
        node = catalog.nodes.get(name)
        if node is None:
            raise DanglingReference(
                obj, f"spec.robots[{k}]", f"ComputeNode {name!r} does not exist"
            )
        if node.spec.tier is not Tier.ROBOT:
            raise InvalidSpec(
                obj,
                f"spec.robots[{k}]",
                f"ComputeNode {name!r} is tier {node.spec.tier.value}, not robot",
            )
        robots.append(node)
    if fleet.spec.robot_selector is not None:
        for node in sorted(catalog.nodes.values(), key=lambda n: n.metadata.name):
            selected = fleet.spec.robot_selector.matches(node.metadata.labels)
            if node.spec.tier is Tier.ROBOT and selected and node not in robots:
                robots.append(node)
    if not robots:
        raise InvalidSpec(obj, "spec.robotSelector", "selects no robot ComputeNode")
    others: list[ComputeNode] = []
    for k, name in enumerate(fleet.spec.nodes):
        node = catalog.nodes.get(name)
        if node is None:
            raise DanglingReference(obj, f"spec.nodes[{k}]", f"ComputeNode {name!r} does not exist")
        if node.spec.tier is Tier.ROBOT:
            raise InvalidSpec(
                obj, f"spec.nodes[{k}]", f"ComputeNode {name!r} is a robot; list it under robots"
            )
        others.append(node)
    if fleet.spec.node_selector is not None:
        for node in sorted(catalog.nodes.values(), key=lambda n: n.metadata.name):
            selected = fleet.spec.node_selector.matches(node.metadata.labels)
            if node.spec.tier is not Tier.ROBOT and selected and node not in others:
                others.append(node)
    return robots, others


def _capacity(node: ComputeNode) -> tuple[float, float, float]:
    cap = node.spec.capacity
    if cap is None:
        raise InvalidSpec(
            f"ComputeNode/{node.metadata.name}",
            "spec.capacity",
            "required when planning offline (the operator reads it from the Node)",
        )
    cpu = parse_cpu(cap.cpu) - parse_cpu(node.spec.reserved.cpu)
    mem = parse_memory(cap.memory) - parse_memory(node.spec.reserved.memory)
    if cpu <= 0:
        raise InvalidSpec(
            f"ComputeNode/{node.metadata.name}",
            "spec.reserved.cpu",
            "reserves all of the node's CPU",
        )
    return cpu, max(mem, 0.0), float(cap.gpu)


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
    obj = f"RobotFleet/{fleet.metadata.name}"
    namespace = fleet.metadata.namespace or "default"
    robots, others = resolve_nodes(fleet, catalog)
    nodes = robots + others
    n = len(nodes)
    caps = np.array([_capacity(nd) for nd in nodes], dtype=np.float64)
    measured = measured_links or {}
    links = [measured.get(nd.metadata.name) or uplink(nd.spec) for nd in nodes]
    robot_index = {nd.metadata.name: j for j, nd in enumerate(robots)}

    modules: list[tuple[SoftwareModule, float, float, int]] = []
    wishes: dict[str, list[Tier]] = {}  # module -> preferred tiers (override, module, fleet)
    priorities: dict[str, int] = {}  # module -> priority (override, module, taxonomy)
    for k, ref in enumerate(fleet.spec.modules):
        mod = catalog.module(namespace, ref.name)
        if mod is None:
            raise DanglingReference(
                obj,
                f"spec.modules[{k}].name",
                f"SoftwareModule {namespace}/{ref.name} does not exist",
            )
        ov = ref.overrides
        cycle = mod.spec.cycle_seconds if ov.cycle_seconds is None else ov.cycle_seconds
        if cycle <= 0:
            raise InvalidSpec(
                obj, f"spec.modules[{k}].overrides.cycleTimeMillis", "must be greater than zero"
            )
        act = (ov.activation_percent or mod.spec.activation_percent) / 100.0
        replicas = ov.replicas or mod.spec.replicas
        modules.append((mod, cycle, act, replicas))
        priorities[mod.metadata.name] = (
            ov.priority if ov.priority is not None else module_priority(mod.spec)
        )
        if ov.preferred_tiers is not None:
            wishes[mod.metadata.name] = ov.preferred_tiers
        else:
            wishes[mod.metadata.name] = mod.spec.preferred_tiers or fleet.spec.preferred_tiers

    node_tier: dict[str, Tier] = {}
    for nd in nodes:
        node_tier[nd.metadata.name] = node_tier[nd.node_name] = nd.spec.tier
    instances: list[Instance] = []
    inst_mod: list[tuple[SoftwareModule, float, float]] = []
    home: list[int] = []
    pool_tier: list[Tier | None] = []
    for mod, cycle, act, replicas in modules:
        if mod.spec.scope is Scope.PER_ROBOT:
            for robot in robots:
                instances.append(Instance(robot.metadata.name, mod.metadata.name, 0))
                inst_mod.append((mod, cycle, act))
                home.append(robot_index[robot.metadata.name])
                pool_tier.append(None)
        else:
            running = {
                r: node_tier[n]
                for (robot, m, r), n in (current or {}).items()
                if not robot and m == mod.metadata.name and n in node_tier
            }
            tiers = _pool_tiers(pools.get(mod.metadata.name) if pools else None, replicas, running)
            for r, tier in enumerate(tiers):
                instances.append(Instance("", mod.metadata.name, r))
                inst_mod.append((mod, cycle, act))
                home.append(-1)
                pool_tier.append(tier)
    i_count = len(instances)

    allowed = np.zeros((i_count, n), dtype=bool)
    net_mean = np.zeros((i_count, n))
    net_std = np.zeros((i_count, n))
    traffic = np.zeros(i_count)
    # the limits pick's cpu, mean, std; the nominal allocation's request, use, mean, std
    lim = (np.zeros((i_count, n)), np.full((i_count, n), np.inf), np.zeros((i_count, n)))
    nom = (
        np.zeros((i_count, n)),
        np.zeros((i_count, n)),
        np.full((i_count, n), np.inf),
        np.zeros((i_count, n)),
    )
    reasons: dict[int, str] = {}
    # Shared replicas talk to the fleet: use the mean robot uplink.
    mean_robot = Link(
        latency=float(np.mean([links[j].latency for j in range(len(robots))])),
        jitter=float(np.mean([links[j].jitter for j in range(len(robots))])),
        bandwidth=float(np.mean([links[j].bandwidth for j in range(len(robots))])),
        loss=float(np.mean([links[j].loss for j in range(len(robots))])),
    )
    table = PairTable(nodes, caps, links, corrections)
    remote = range(len(robots), n)  # edge and cloud nodes: one block per module and link
    blocks: list[Block] = []
    home_rungs: dict[int, tuple[ProfileRow, ...]] = {}
    for i, (inst, (mod, cycle, _act), h) in enumerate(zip(instances, inst_mod, home, strict=True)):
        why: list[str] = []
        if h >= 0:
            own = table.pair(mod, cycle, pool_tier[i], h, h, links[h])
            if isinstance(own, Pair):
                allowed[i, h] = True
                net_mean[i, h], net_std[i, h] = own.net_mean, own.net_std
                for arr, v in zip(lim, (own.pick.cpu, own.pick.mean, own.pick.std), strict=True):
                    arr[i, h] = v
                nominal = (
                    parse_cpu(mod.spec.resources.cpu),
                    own.top.cpu,
                    own.top.mean,
                    own.top.std,
                )
                for arr, v in zip(nom, nominal, strict=True):
                    arr[i, h] = v
                if own.rungs:
                    home_rungs[i] = own.rungs
            elif own is not None:
                why.append(own)
        blk = table.block(mod, cycle, pool_tier[i], remote, links[h] if h >= 0 else mean_robot)
        blocks.append(blk)
        allowed[i, remote.start :] = blk.allowed
        net_mean[i, remote.start :] = blk.net_mean
        net_std[i, remote.start :] = blk.net_std
        for arr, row in zip((*lim, *nom), (*blk.lim, *blk.nom), strict=True):
            arr[i, remote.start :] = row
        if blk.allowed.any():
            traffic[i] = blk.bits
        why += blk.why
        if not allowed[i].any():
            where = "; ".join(why) if why else "no node in the fleet can host it"
            reasons[i] = (
                f"{inst.robot + '/' if inst.robot else ''}{inst.module} fits nowhere: {where}"
            )
    lim_req, lim_exe, lim_std = lim
    nom_req, nom_use, nom_exe, nom_std = nom

    cur = np.full(i_count, -1, dtype=np.int64)
    if current:
        by_name: dict[str, list[int]] = {}
        for j, nd in enumerate(nodes):
            for key in dict.fromkeys((nd.metadata.name, nd.node_name)):
                by_name.setdefault(key, []).append(j)
        for i, inst in enumerate(instances):
            node_name = current.get((inst.robot, inst.module, inst.replica))
            for j in by_name.get(node_name, []) if node_name is not None else []:
                if allowed[i, j]:
                    cur[i] = j

    power = np.zeros((n, 4))
    for j, nd in enumerate(nodes):
        p = nd.spec.power
        if p is not None:
            power[j] = [
                parse_quantity(p.battery_watt_hours),
                parse_quantity(p.idle_watts),
                parse_quantity(p.per_core_watts),
                parse_quantity(p.radio_watts_per_mbps),
            ]

    mem = (
        np.array([parse_memory(m.spec.resources.memory) for m, _, _ in inst_mod])
        if inst_mod
        else np.zeros(0)
    )
    gpu = (
        np.array([float(m.spec.resources.gpu) for m, _, _ in inst_mod]) if inst_mod else np.zeros(0)
    )
    preferred = None
    if any(wishes.values()):
        tiers = [nd.spec.tier for nd in nodes]
        names = list(dict.fromkeys(inst.module for inst in instances))
        by_module = np.array(
            [[not wishes[m] or t in wishes[m] for t in tiers] for m in names], dtype=bool
        ).reshape(len(names), n)
        which = {m: k for k, m in enumerate(names)}
        rows = np.array([which[inst.module] for inst in instances], dtype=np.int64)
        preferred = freeze(by_module[rows].reshape(i_count, n))
    held = standbys(fleet, catalog, modules, instances, home, robots, allowed, lim, home_rungs)
    return Problem(
        fallback=held.keep,
        fallback_row=held.row,
        fallback_variant=held.variant,
        fallback_cycle=held.cycle,
        fallback_need=held.need,
        preferred=preferred,
        priority=freeze(np.array([priorities[inst.module] for inst in instances], dtype=np.int64)),
        ladder_source=_lazy_ladder(blocks, home, home_rungs, remote, lim),
        fleet=fleet.metadata.name,
        namespace=namespace,
        nodes=tuple(
            NodeInfo(
                nd.metadata.name,
                nd.node_name,
                nd.spec.tier,
                nd.spec.hardware_type,
                parse_quantity(nd.spec.speed_factor),
            )
            for nd in nodes
        ),
        instances=tuple(instances),
        tier=freeze(np.array([TIER_CODE[nd.spec.tier] for nd in nodes], dtype=np.int64)),
        capacity=freeze(caps),
        cost=freeze(np.array([parse_quantity(nd.spec.cost_per_core_hour) for nd in nodes])),
        power=freeze(power),
        uplink_bandwidth=freeze(np.array([lk.bandwidth for lk in links])),
        home=freeze(np.array(home, dtype=np.int64)),
        allowed=freeze(allowed),
        activation=freeze(np.array([a for _, _, a in inst_mod])),
        cycle=freeze(np.array([c for _, c, _ in inst_mod])),
        memory=freeze(mem),
        gpu=freeze(gpu),
        net_mean=freeze(net_mean),
        net_std=freeze(net_std),
        traffic=freeze(traffic),
        limits=Allocation(freeze(lim_req), lim_req, freeze(lim_exe), freeze(lim_std), True),
        nominal=Allocation(
            freeze(nom_req), freeze(nom_use), freeze(nom_exe), freeze(nom_std), False
        ),
        current=freeze(cur),
        reasons=reasons,
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
