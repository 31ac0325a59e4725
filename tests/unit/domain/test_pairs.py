"""build_problem copies one block per (module, robot uplink) into every instance: the result
must equal evaluating every (instance, node) pair on its own."""

from __future__ import annotations

import numpy as np

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.network import uplink
from fogfleet.domain.pairs import Pair, PairTable, pad_rungs


def _fleet_with_a_slow_robot() -> tuple[Catalog, object]:
    """12 robots on 5 edges; robot 3's Wi-Fi is ten times slower than the others', and the
    first edge has one core (modules profiled only above it may not run there)."""
    cat, fleet = synthetic_fleet(12, 5, 4)
    edge = cat.nodes[fleet.spec.nodes[0]]
    assert edge.spec.capacity is not None
    cap = edge.spec.capacity.model_copy(update={"cpu": 1})
    cat.nodes[edge.metadata.name] = edge.model_copy(
        update={"spec": edge.spec.model_copy(update={"capacity": cap})}
    )
    name = fleet.spec.robots[2]
    robot = cat.nodes[name]
    links = [
        link.model_copy(update={"latency_millis": 40, "bandwidth_mbps": 20})
        for link in robot.spec.network
    ]
    assert links, "the synthetic robot declares its uplink"
    cat.nodes[name] = robot.model_copy(
        update={"spec": robot.spec.model_copy(update={"network": links})}
    )
    return cat, fleet


def test_the_blocks_equal_the_pairs_one_by_one() -> None:
    cat, fleet = _fleet_with_a_slow_robot()
    p = build_problem(fleet, cat)  # type: ignore[arg-type]
    robots = [cat.nodes[n] for n in fleet.spec.robots]  # type: ignore[attr-defined]
    others = [cat.nodes[n] for n in fleet.spec.nodes]  # type: ignore[attr-defined]
    nodes = robots + others
    caps = p.capacity
    links = [uplink(nd.spec) for nd in nodes]
    table = PairTable(nodes, caps, links)
    modules = {m.metadata.name: m for m in cat.modules.values()}
    cycles = dict(zip(p.instances, p.cycle, strict=True))
    k = p.ladder.cpu.shape[2] if p.ladder is not None else 1
    slow = links[2]
    assert slow != links[0]
    seen_slow = False
    for i, inst in enumerate(p.instances):
        h = int(p.home[i])
        assert h >= 0 and nodes[h].spec.tier is Tier.ROBOT
        bits = 0.0
        for j in range(len(nodes)):
            got = table.pair(modules[inst.module], cycles[inst], None, j, h, links[h])
            assert p.allowed[i, j] == isinstance(got, Pair), (inst, j)
            if not isinstance(got, Pair):
                continue
            bits = got.bits if j != h else bits
            assert p.net_mean[i, j] == got.net_mean and p.net_std[i, j] == got.net_std
            assert p.limits.cpu_request[i, j] == got.pick.cpu
            assert p.limits.exe_mean[i, j] == got.pick.mean
            assert p.nominal.cpu_use[i, j] == got.top.cpu
            if p.ladder is not None:
                want = pad_rungs(got.rungs or (got.pick,), k)
                assert list(p.ladder.cpu[i, j]) == [r[0] for r in want]
                assert p.ladder.depth[i, j] == max(len(got.rungs) - 1, 0)
            seen_slow |= h == 2 and j != h
        assert p.traffic[i] == bits, inst
    assert seen_slow
    partly = p.allowed[:, p.tier == 1].any(axis=1) & ~p.allowed[:, p.tier == 1].all(axis=1)
    assert partly.any(), "some instance may run on some edges only"
    # the slow robot's offloaded instances pay for their slower link
    off = p.tier == 1
    slow_rows = p.home == 2
    fast_rows = p.home == 0
    assert np.all(p.net_mean[slow_rows][:, off] >= p.net_mean[fast_rows][:, off])
    assert np.any(p.net_mean[slow_rows][:, off] > p.net_mean[fast_rows][:, off])
