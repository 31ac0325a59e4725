"""Nodes that are down (stickiness.mask_unavailable): an edge node's modules are planned
anew elsewhere; a robot that is down keeps its modules where they run."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.stickiness import mask_unavailable


def test_a_down_edge_nodes_modules_may_go_anywhere_else(tiny: Problem) -> None:
    p = replace(tiny, current=np.array([0, 1, 2]))
    masked, stranded = mask_unavailable(p, {1: "NotReady"})
    assert stranded == set()
    assert masked.allowed[1].tolist() == [True, False, True]  # robot or the other edge
    assert masked.current.tolist() == [0, -1, 2]


def test_a_down_robot_strands_its_onboard_modules_and_pins_the_others(tiny: Problem) -> None:
    p = replace(tiny, current=np.array([0, 1, 0]))
    masked, stranded = mask_unavailable(p, {0: "NotReady (NodeStatusUnknown)"})
    # instance 0 is pinned on board, instance 2 ran on board: nothing left for them
    assert stranded == {0, 2}
    assert "n0 is NotReady" in masked.reasons[0]
    # instance 1 runs on edge node 1: it stays there, nowhere else
    assert masked.allowed[1].tolist() == [False, True, False]


def test_a_down_robots_module_on_a_node_it_may_no_longer_use_is_stranded(tiny: Problem) -> None:
    allowed = tiny.allowed.copy()
    allowed[1, 1] = False  # its requirements changed: edge node 1 is no longer allowed
    p = replace(tiny, current=np.array([0, 1, 2]), allowed=allowed)
    masked, stranded = mask_unavailable(p, {0: "NotReady"})
    assert 1 in stranded and not masked.allowed[1].any()
