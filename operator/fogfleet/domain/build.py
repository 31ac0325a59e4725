"""``build_problem``: a fleet, its catalogue (modules, ComputeNodes) and the current placement
into the immutable ``Problem`` (the gene spaces of multi-robot-edge-cloud-scheduling III-E, the
allocations of IV-B, eq. 4's transfer times per instance and node)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.base import parse_cpu, parse_memory, parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import Scope, SoftwareModule
from fogfleet.errors import DanglingReference, InvalidSpec

from .network import LOCAL, Link, path, uplink
from .problem import (
    EXEC_SHARE_OF_CYCLE,
    TIER_CODE,
    Allocation,
    Instance,
    Ladder,
    NodeInfo,
    Problem,
    freeze,
)
from .taxonomy import may_degrade, module_priority, must_stay_onboard

__all__ = ["build_problem"]

F64 = NDArray[np.float64]


def _resolve_nodes(
    fleet: RobotFleet, catalog: Catalog
) -> tuple[list[ComputeNode], list[ComputeNode]]:
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


@dataclass(frozen=True)
class _Row:
    cpu: float
    mean: float
    std: float


def _profile_rows(module: SoftwareModule, node: ComputeNode) -> list[_Row]:
    """Fig. 3 rows for this node's hardware type; 'default' rows scaled by speedFactor."""
    own = [r for r in module.spec.profile if r.hardware_type == node.spec.hardware_type]
    scale = 1.0
    if not own:
        own = [r for r in module.spec.profile if r.hardware_type == "default"]
        scale = 1.0 / max(parse_quantity(node.spec.speed_factor), 1e-6)
    rows = [
        _Row(
            parse_cpu(r.cpu),
            parse_quantity(r.mean_millis) / 1e3 * scale,
            parse_quantity(r.std_millis) / 1e3 * scale,
        )
        for r in own
    ]
    return sorted(rows, key=lambda r: r.cpu)


def _transfer(module: SoftwareModule, link: Link) -> tuple[float, float, float]:
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
) -> Problem:
    """Resolve a fleet against the catalog into a Problem.

    ``current`` maps (robot, module, replica) to the node it runs on now. ``pools`` gives the
    autoscaler's decision for shared modules: module name -> {tier: replicas} (tier ``any``:
    replicas without a pool); replica ``r`` of
    such a module may then only run on nodes of the tier it was counted for (edge replicas
    first, then cloud), which is how privacy-constrained pools stay on the edge."""
    obj = f"RobotFleet/{fleet.metadata.name}"
    namespace = fleet.metadata.namespace or "default"
    robots, others = _resolve_nodes(fleet, catalog)
    nodes = robots + others
    n = len(nodes)
    caps = np.array([_capacity(nd) for nd in nodes], dtype=np.float64)
    links = [uplink(nd.spec) for nd in nodes]
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
        cycle = (
            parse_quantity(
                ov.cycle_time_millis
                if ov.cycle_time_millis is not None
                else mod.spec.cycle_time_millis
            )
            / 1e3
        )
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
    lim_req = np.zeros((i_count, n))
    lim_exe = np.full((i_count, n), np.inf)
    lim_std = np.zeros((i_count, n))
    nom_req = np.zeros((i_count, n))
    nom_use = np.zeros((i_count, n))
    nom_exe = np.full((i_count, n), np.inf)
    nom_std = np.zeros((i_count, n))
    reasons: dict[int, str] = {}
    rungs: dict[tuple[int, int], list[_Row]] = {}  # smaller profiled CPUs below the pick
    # the same module on the same hardware / over the same link: computed once per build
    profiles: dict[tuple[int, str, Any], list[_Row]] = {}
    transfers: dict[tuple[int, Link], tuple[float, float, float]] = {}
    # Shared replicas talk to the fleet: use the mean robot uplink.
    mean_robot = Link(
        latency=float(np.mean([links[j].latency for j in range(len(robots))])),
        jitter=float(np.mean([links[j].jitter for j in range(len(robots))])),
        bandwidth=float(np.mean([links[j].bandwidth for j in range(len(robots))])),
        loss=float(np.mean([links[j].loss for j in range(len(robots))])),
    )

    for i, (inst, (mod, cycle, _act), h) in enumerate(zip(instances, inst_mod, home, strict=True)):
        spec = mod.spec
        req = spec.requirements
        onboard_only = must_stay_onboard(spec.taxonomy)
        why: list[str] = []
        nominal_cpu = parse_cpu(spec.resources.cpu)
        for j, nd in enumerate(nodes):
            ns = nd.spec
            name = nd.metadata.name
            if ns.tier is Tier.ROBOT and j != h:
                continue  # never another robot's computer (III-E); shared replicas never on robots
            if onboard_only and j != h:
                why.append(
                    f"{name}: module is hard real-time or safety-critical, so it stays on its robot"
                )
                continue
            if req.tiers and ns.tier not in req.tiers:
                why.append(f"{name}: tier {ns.tier.value} not in requirements.tiers")
                continue
            if pool_tier[i] is not None and ns.tier is not pool_tier[i]:
                continue  # a replica counted for another tier's pool
            have = {d.type for d in ns.devices}
            missing = [d.value for d in req.devices if d not in have]
            if missing:
                why.append(f"{name}: lacks device {', '.join(missing)}")
                continue
            if req.gpu and caps[j, 2] < 1:
                why.append(f"{name}: no GPU")
                continue
            if req.realtime_kernel and not ns.realtime_kernel:
                why.append(f"{name}: no real-time kernel")
                continue
            if ns.privacy < req.min_privacy:
                why.append(f"{name}: privacy level {ns.privacy} < required {req.min_privacy}")
                continue
            key = (id(mod), ns.hardware_type, ns.speed_factor)
            if key not in profiles:
                profiles[key] = _profile_rows(mod, nd)
            rows = [r for r in profiles[key] if r.cpu <= caps[j, 0] + 1e-9]
            if not rows:
                why.append(
                    f"{name}: no execution-time profile for hardware type "
                    f"{ns.hardware_type!r} that fits its CPU"
                )
                continue
            link = LOCAL if j == h else path(links[h] if h >= 0 else mean_robot, links[j])
            if (id(mod), link) not in transfers:
                transfers[id(mod), link] = _transfer(mod, link)
            t, s, bits = transfers[id(mod), link]
            net_mean[i, j], net_std[i, j] = t, s
            if j != h:
                traffic[i] = bits
            # limits: the smallest CPU whose mean + 2 std fits the cycle's share, else the fastest
            budget = EXEC_SHARE_OF_CYCLE * cycle - t
            fit = [r for r in rows if r.mean + 2 * r.std <= budget]
            pick = fit[0] if fit else min(rows, key=lambda r: (r.mean, r.cpu))
            lim_req[i, j], lim_exe[i, j], lim_std[i, j] = pick.cpu, pick.mean, pick.std
            if may_degrade(spec.taxonomy):
                rungs[i, j] = [
                    pick,
                    *sorted((r for r in rows if r.cpu < pick.cpu), key=lambda r: -r.cpu),
                ]
            # nominal: request as declared, no limit, uses the largest profiled parallelism
            top = rows[-1]
            nom_req[i, j], nom_use[i, j] = nominal_cpu, top.cpu
            nom_exe[i, j], nom_std[i, j] = top.mean, top.std
            allowed[i, j] = True
        if not allowed[i].any():
            where = "; ".join(why) if why else "no node in the fleet can host it"
            reasons[i] = (
                f"{inst.robot + '/' if inst.robot else ''}{inst.module} fits nowhere: {where}"
            )

    cur = np.full(i_count, -1, dtype=np.int64)
    if current:
        for i, inst in enumerate(instances):
            node_name = current.get((inst.robot, inst.module, inst.replica))
            if node_name is None:
                continue
            for j, nd in enumerate(nodes):
                if node_name in (nd.metadata.name, nd.node_name) and allowed[i, j]:
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
        preferred = np.array(
            [
                [not wishes[inst.module] or t in wishes[inst.module] for t in tiers]
                for inst in instances
            ],
            dtype=bool,
        ).reshape(i_count, n)
        preferred = freeze(preferred)
    return Problem(
        preferred=preferred,
        priority=freeze(np.array([priorities[inst.module] for inst in instances], dtype=np.int64)),
        ladder=_ladder(rungs, lim_req, lim_exe, lim_std),
        fleet=fleet.metadata.name,
        namespace=namespace,
        nodes=tuple(
            NodeInfo(nd.metadata.name, nd.node_name, nd.spec.tier, nd.spec.hardware_type)
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
        limits=Allocation(
            freeze(lim_req), freeze(lim_req.copy()), freeze(lim_exe), freeze(lim_std), True
        ),
        nominal=Allocation(
            freeze(nom_req), freeze(nom_use), freeze(nom_exe), freeze(nom_std), False
        ),
        current=freeze(cur),
        reasons=reasons,
    )


def _ladder(
    rungs: Mapping[tuple[int, int], list[_Row]], cpu: F64, mean: F64, std: F64
) -> Ladder | None:
    """Rung 0 is the limits pick everywhere; deeper rungs only where a module may degrade and
    its profile has smaller CPU rows for that node (padded with the smallest)."""
    depth = np.zeros(cpu.shape, dtype=np.int64)
    for (i, j), rows in rungs.items():
        depth[i, j] = len(rows) - 1
    if not depth.any():
        return None
    k = int(depth.max()) + 1
    lc = np.repeat(cpu[:, :, None], k, axis=2)
    lm = np.repeat(mean[:, :, None], k, axis=2)
    ls = np.repeat(std[:, :, None], k, axis=2)
    for (i, j), rows in rungs.items():
        padded = rows + [rows[-1]] * (k - len(rows))
        lc[i, j] = [r.cpu for r in padded]
        lm[i, j] = [r.mean for r in padded]
        ls[i, j] = [r.std for r in padded]
    return Ladder(freeze(lc), freeze(lm), freeze(ls), freeze(depth))
