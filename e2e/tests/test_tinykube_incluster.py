"""tinyKube's autoscaling scenario against the operator as users install it (issue 44).

The shared-detector example, unchanged (an edge pool of at most 17 replicas and a cloud pool
of at most 19, predictive mode, tinyKube's behaviour), is scaled by the operator installed
in-cluster by its chart, reading the bed's Prometheus at its cluster address. The twin plays
the requests on the replicas that run (kwok pods) and counts what they met as ``make bench``'s
autoscaling suite counts it (:mod:`fogfleet.twin.tally`).

Protocol, fixed before the first result:

* load: phases 1-4 of the benchmark's first held-out seed (10), 5 000 requests each at the
  phase's rate and privacy share (4 of its 12 phases: a scale factor of 1/3 of one seed,
  about 250 s), after 30 s at the first phase's rate that is not counted (the benchmark starts
  with 5 ready replicas per pool; here the operator sizes the pools for the first rate);
* the operator decides every 2.5 s, the benchmark's period, and reads the offered rate over
  5 s, the benchmark's window (``scaling.rateWindowSeconds``); the rest is the chart's default;
* one run; issue 44's target is every figure within twice the benchmark's median for its
  ``predictive`` column in ``bench-autoscaling.json`` (the example's mode): the test prints
  both side by side.

The first valid run (2026-11-28) left the rate window at the operator's fixed 10 s, which the
benchmark never modelled; it met the target for normal rejections (0.22 % against a 0.62 %
bound) and SLO violations (9.0 % against 15.1 %) and missed it for private ones (0.645 %
against 0.603 %): with twice the window the operator sees a surge about 5 s later (of some
6 000 private requests, 39 were rejected where the target allows 36). The window then became
a chart setting, and this protocol (its second version) sets it to the benchmark's, as it
already set the period. Its first run (2026-11-28) rejected 0.257 % of private and 0.080 % of
normal requests and missed 7.8 % of SLOs (bench medians 0.302 %, 0.312 %, 7.5 %). The test
asserts three times the benchmark, a guard that the tinyKube preset's minute-long hold before
any scale-up (27 % and 37 % rejected) fails by far.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import example_in, free_port, of_kind
from e2e.tests.incluster import installed
from e2e.tests.scaling_rig import delete_fleet_objects, look
from fogfleet.adapters.kube import KubeClient, load_config
from fogfleet.bench.autoscaling import RATE_WINDOW_SECONDS, REQUESTS_PER_PHASE, make_workload
from fogfleet.twin.app import Twin

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.long,
    pytest.mark.incluster,
    pytest.mark.inclusterloop,
    pytest.mark.bed(
        "the bed's in-cluster Prometheus, its real nodes and the warehouse's kwok nodes"
    ),
    pytest.mark.timeout(720),
]

REPO = Path(__file__).resolve().parents[2]
MODULE = "object-detector"
SEED, PHASES = 10, 4
WARM_UP_SECONDS = 30
INTERVAL_SECONDS = 2.5  # the benchmark's decision period
POLICY = "predictive"  # the example's mode
TARGET, GUARD = 2, 3  # issue 44's target (printed), what the test asserts (see above)
Obj = dict[str, Any]


def example_docs(namespace: str) -> tuple[list[Obj], list[Obj], Obj]:
    """The shared-detector example in ``namespace``: (ComputeNodes, modules, fleet)."""
    docs = example_in("shared-detector", namespace)
    return (
        of_kind(docs, "ComputeNode"),
        of_kind(docs, "SoftwareModule"),
        of_kind(docs, "RobotFleet")[0],
    )


def phases() -> list[tuple[float, float, float]]:
    """(requests/s, private share, seconds) of the benchmark's phases played here."""
    w = make_workload(SEED)
    out = []
    for i, (_, rate) in enumerate(w.phases[:PHASES]):
        private = w.private[i * REQUESTS_PER_PHASE : (i + 1) * REQUESTS_PER_PHASE]
        out.append((rate, float(private.mean()), REQUESTS_PER_PHASE / rate))
    return out


def bench_figures() -> dict[str, float]:
    """The benchmark's median per metric for POLICY, over its recorded seeds."""
    runs = json.loads((REPO / "bench-autoscaling.json").read_text())["result"].values()
    metrics = ("privacyRejected", "normalRejected", "sloViolations")
    return {m: statistics.median(r[POLICY][m] for r in runs) for m in metrics}


@pytest.fixture
def twin(kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path) -> Iterator[Twin]:
    _, share, _ = phases()[0]
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({"services": [{
        "module": MODULE, "namespace": namespace, "privateShare": share,
        "phases": [{"atSeconds": 0, "requestsPerSecond": 0}]}]}))  # fmt: skip
    t = Twin(KubeClient(load_config(str(kube.kubeconfig))), scenario, port=free_port(),
             namespace=namespace, poll_seconds=0.5, seed=SEED)  # fmt: skip
    t.start()
    cluster.add_prometheus_target(f"twin-{namespace}", f"127.0.0.1:{t.port}")
    yield t
    cluster.remove_prometheus_target(f"twin-{namespace}")
    t.stop()


def test_the_installed_operator_scales_tinykubes_scenario_near_the_benchmark(
    kube: Kube, cluster: Cluster, crds: None, namespace: str, twin: Twin,
    diagnostics: list[Any],
) -> None:  # fmt: skip
    nodes, modules, fleet = example_docs(namespace)
    kube.apply(nodes + modules)
    kube.apply(fleet)
    seen: list[str] = []
    diagnostics.append(lambda: ("pools over time", "\n".join(seen)))
    values: dict[str, str | float] = {
        "scaling.prometheusUrl": cluster.in_cluster_prometheus_url,
        "scaling.intervalSeconds": INTERVAL_SECONDS,
        "scaling.rateWindowSeconds": int(RATE_WINDOW_SECONDS),
    }
    t0 = time.monotonic()

    def watch(seconds: float) -> None:
        """Keep a record of the decision and the running replicas for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            s = look(kube, namespace, t0)
            seen.append(f"{s.t:5.0f}s decided {s.pools}, running edge {len(s.on('edge'))} "
                        f"cloud {len(s.on('cloud'))}")  # fmt: skip
            time.sleep(max(0.0, min(5.0, end - time.monotonic())))

    with installed(kube, values=values, namespace=namespace):
        kube.wait_for("the detector's first replicas to run",
                      lambda: len(look(kube, namespace, t0).pods) >= 1, timeout=120)  # fmt: skip
        plan = phases()
        twin.set_load(namespace, MODULE, plan[0][0], plan[0][1])
        watch(WARM_UP_SECONDS)
        start = twin.tally(namespace, MODULE)
        assert start.served > 0, "the twin answered no request: no replica is ready"
        for rate, share, seconds in plan:
            twin.set_load(namespace, MODULE, rate, share)
            seen.append(f"phase: {rate:.1f} requests/s, {share:.0%} private, {seconds:.0f} s")
            watch(seconds)
        counted = twin.tally(namespace, MODULE).since(start)
        selector = f"involvedObject.name={MODULE},reason=ScaledUp"
        scaled_up = kube.kubectl_json(
            "get", "events", "-n", namespace, "--field-selector", selector
        )["items"]
        delete_fleet_objects(kube, namespace)

    got, bench = counted.figures(), bench_figures()
    print(f"\ntinyKube scenario, seed {SEED} phases 1-{PHASES} "
          f"({counted.private_arrived + counted.normal_arrived} requests), in-cluster operator "
          f"vs make bench ({POLICY}, median):")  # fmt: skip
    for metric, value in got.items():
        bound = TARGET * bench[metric]
        verdict = "within" if value <= bound else "OVER"
        print(f"  {metric:16s} {value:8.3%}   bench {bench[metric]:8.3%}   "
              f"target {bound:8.3%} ({verdict})")  # fmt: skip
    print("\n".join(seen))
    assert scaled_up, "the operator never scaled the detector up"
    assert counted.private_arrived + counted.normal_arrived > 0.9 * PHASES * REQUESTS_PER_PHASE
    over = {m: (v, GUARD * bench[m]) for m, v in got.items() if v > GUARD * bench[m]}
    assert not over, f"over {GUARD} times the benchmark (measured, bound): {over}"
