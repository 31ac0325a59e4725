"""The Events of a fleet's nodes going away and coming back (node_events.py), and the
controller posting them once per change (a rebooted node, issue 37)."""

from __future__ import annotations

from fogfleet.controllers.fleet.node_events import node_events
from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")
HOSTED = {"edge-1": ["r1/detector", "r2/detector", "r2/planner"], "r1": ["r1/camera"]}


def test_a_node_going_away_names_itself_why_and_its_modules():
    (event,) = node_events({}, {"edge-1": "NotReady (NodeStatusUnknown)"}, HOSTED, {"r1/detector"})
    kind, reason, message = event
    assert (kind, reason) == ("Warning", "NodeUnavailable")
    assert message == (
        "Node edge-1 is NotReady (NodeStatusUnknown): 3 module(s) ran there: r1/detector, "
        "r2/detector, r2/planner; 1 wait for it (no other node allowed); 2 planned on other nodes"
    )


def test_a_node_coming_back_is_one_normal_event():
    before = {"edge-1": "NotReady (NodeStatusUnknown)", "spare": "cordoned"}
    events = node_events(before, {"spare": "cordoned"}, HOSTED, set())
    assert events == [
        ("Normal", "NodeAvailable",
         "Node edge-1 is available again: 3 module(s) bound to it: r1/detector, r2/detector, "
         "r2/planner"),
    ]  # fmt: skip


def test_an_unchanged_set_of_unavailable_nodes_posts_nothing():
    down = {"edge-1": "cordoned"}
    assert node_events(down, down, HOSTED, set()) == []
    assert node_events({}, {}, HOSTED, set()) == []


def test_an_empty_node_going_away_says_no_module_ran_there():
    ((_, _, message),) = node_events({}, {"spare": "cordoned"}, HOSTED, set())
    assert message == "Node spare is cordoned: no module of the fleet ran there"


def test_a_long_list_of_modules_is_cut_with_a_count():
    many = {"n": [f"r{i}/m" for i in range(13)]}
    ((_, _, message),) = node_events({}, {"n": "cordoned"}, many, set())
    assert message.endswith("r9/m and 3 more; 13 planned on other nodes")


def test_the_controller_posts_a_down_robot_once_and_its_return(kube, deps):
    """robot-1 NotReady: one Warning naming it and its on-board modules (they wait for it),
    not repeated by the next pass; Ready again: one Normal."""
    reconcile(kube.get_fleet(*KEY), deps)
    kube.run_pods()
    reconcile(kube.get_fleet(*KEY), deps)
    assert not [e for e in kube.events if e[1].startswith("Node")]
    kube.set_ready("robot-1", False)
    reconcile(kube.get_fleet(*KEY), deps)
    reconcile(kube.get_fleet(*KEY), deps)
    down = [e for e in kube.events if e[1] == "NodeUnavailable"]
    assert len(down) == 1, down
    kind, _, message = down[0]
    assert kind == "Warning"
    assert message.startswith("Node robot-1 is NotReady (KubeletNotReady): ")
    assert "robot-1/" in message and "wait for it (no other node allowed)" in message
    kube.set_ready("robot-1", True)
    reconcile(kube.get_fleet(*KEY), deps)
    back = [e for e in kube.events if e[1] == "NodeAvailable"]
    assert len(back) == 1 and back[0][2].startswith("Node robot-1 is available again: ")
