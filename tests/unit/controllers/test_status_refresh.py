"""The status refresh: while only the rollout moves, a reconcile reuses the rendered
Deployments; any input the full pass reads sends it down the full pass again."""

from __future__ import annotations

import pytest
from test_rollout import desired  # the same directory: pytest puts it on sys.path

import fogfleet.controllers.fleet.plan as fleet_plan
import fogfleet.controllers.fleet.reconcile as robotfleet
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.stamp import resync_overdue
from fogfleet.render.wiring import is_ros_object

KEY = ("warehouse", "warehouse")


@pytest.fixture
def builds(monkeypatch):
    """How many times the full pass built the problem."""
    count = [0]
    real = fleet_plan.build

    def counting(*args, **kwargs):
        count[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(fleet_plan, "build", counting)
    return count


def run(kube, deps):
    return reconcile(kube.get_fleet(*KEY), deps)


def ready(kube) -> str:
    conds = {c["type"]: c for c in kube.fleets[KEY]["status"]["conditions"]}
    return conds["Ready"]["status"]


def test_pods_starting_only_refresh_the_status(kube, deps, builds):
    run(kube, deps)
    assert builds[0] == 1 and ready(kube) == "False"
    run(kube, deps)  # nothing changed, nothing runs yet
    kube.run_pods()
    out = run(kube, deps)
    assert builds[0] == 1, "the rollout's progress alone must not rebuild and re-render"
    assert out.ready and ready(kube) == "True" and out.applied == 0


def test_a_module_edit_runs_the_full_pass(kube, deps, builds):
    run(kube, deps)
    module = kube.modules[("warehouse", "nav-localization")]
    module["metadata"]["generation"] += 1
    run(kube, deps)
    assert builds[0] == 2


def test_a_node_going_not_ready_runs_the_full_pass(kube, deps, builds):
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    kube.set_ready("edge-1", False)
    run(kube, deps)
    assert builds[0] == 2
    kube.nodes["edge-1"]["status"]["conditions"][0]["lastHeartbeatTime"] = "now"
    run(kube, deps)  # a heartbeat is not an input
    assert builds[0] == 2


def test_a_deployment_deleted_by_hand_is_put_back(kube, deps, builds):
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    name = next(k for k, d in kube.deployments.items() if not is_ros_object(d))
    del kube.deployments[name]
    out = run(kube, deps)
    assert builds[0] == 2 and out.applied == 1 and name in kube.deployments


def test_a_render_older_than_the_full_reconcile_period_is_not_reused(kube, deps, builds):
    deps.full_reconcile_seconds = 0.0
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    assert builds[0] == 2


def test_a_failed_full_pass_leaves_nothing_to_reuse(kube, deps, builds):
    run(kube, deps)
    assert deps.store.state(KEY).rendered is not None
    kube.fleets[KEY]["spec"]["modules"].append({"name": "no-such-module"})
    kube.fleets[KEY]["metadata"]["generation"] = 2
    with pytest.raises(Exception, match="no-such-module"):
        run(kube, deps)
    assert deps.store.state(KEY).rendered is None


def test_a_rollout_puts_the_re_render_off_until_its_last_pod_runs(kube, deps, builds):
    """An old render is re-done only once the refresh has found every module running (and
    said Ready first): a re-render that began just before the last pod ran held Ready back."""
    deps.full_reconcile_seconds = 0.0  # every render is due at once
    run(kube, deps)
    run(kube, deps)  # nothing runs yet: the rollout goes on, no re-render
    assert builds[0] == 1 and ready(kube) == "False"
    kube.run_pods()
    patches = len(kube.status_patches)
    out = run(kube, deps)
    assert out.ready and builds[0] == 2
    said = [p for p in kube.status_patches[patches:] if p.get("conditions")]
    assert said and any(
        c["type"] == "Ready" and c["status"] == "True" for c in said[0]["conditions"]
    ), "the refresh says Ready before the re-render"
    assert len(said) == 1, "the re-render finds nothing new to say"


def test_a_rollout_that_never_ends_is_re_rendered_after_all(kube, deps, builds, monkeypatch):
    monkeypatch.setattr(robotfleet, "RESYNC_MAX_DEFER_SECONDS", 0.0)
    deps.full_reconcile_seconds = 0.0
    run(kube, deps)
    run(kube, deps)
    assert builds[0] == 2


def test_a_render_is_due_after_the_period_or_ten_times_what_it_took():
    assert resync_overdue(at=0.0, took=1.0, period=60.0, now=59.0) is None
    assert resync_overdue(at=0.0, took=1.0, period=60.0, now=61.0) == 1.0
    # a 15 s full pass (1000 robots) is re-done every 150 s, not every minute
    assert resync_overdue(at=0.0, took=15.0, period=60.0, now=100.0) is None
    assert resync_overdue(at=0.0, took=15.0, period=60.0, now=160.0) == 10.0
    assert resync_overdue(at=0.0, took=15.0, period=0.0, now=0.0) == 0.0


def _dep(name: str, spec_hash: str, node: str) -> dict:
    return desired(name, (node,), spec_hash)


def _afresh(deps: list[dict]) -> tuple:
    """The Deployments' part computed from scratch, each Deployment read."""
    from fogfleet.controllers import stamp

    return tuple(sorted(stamp._deployment(d) for d in deps))


def test_the_deployments_stamp_is_remembered_per_object_and_follows_every_replacement(
    monkeypatch,
):
    from fogfleet.controllers import stamp

    computed: list[str] = []
    plain = stamp._deployment
    monkeypatch.setattr(
        stamp, "_deployment", lambda d: computed.append(d["metadata"]["name"]) or plain(d)
    )
    memo = stamp.DeploymentStamps()
    deps = [_dep("a", "h1", "edge-1"), _dep("b", "h1", "edge-2")]
    first = memo(deps)
    assert first == _afresh(deps)
    computed.clear()
    assert memo(list(deps)) == first and computed == []  # the same objects: nothing re-read
    # the cache replaced b (re-bound to another node): only b is read again, and it shows
    moved = [deps[0], _dep("b", "h1", "edge-3")]
    computed.clear()
    assert memo(moved) != first and computed == ["b"]
    assert memo(moved) == _afresh(moved)
    # one gone, or a new object equal to the old one: the same stamp as computed afresh
    assert memo(moved[:1]) == _afresh(moved[:1])
    assert memo([_dep("a", "h1", "edge-1")]) == _afresh(moved[:1])
