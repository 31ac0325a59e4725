"""Fast checks of the harness and the kubeconfig guard (no cluster, no network)."""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path

import pytest

from e2e.bed import gomodule, harness
from e2e.bed.fakenodes import SIMULATED_TAINT
from e2e.bed.kube import UnsafeKubeconfig, guard_kubeconfig
from e2e.bed.realnodes import split_manifest
from fogfleet.api.labels import DEDICATED_TAINT_KEY
from fogfleet.render.ros import PLANNED_TOLERATION


def _kubeconfig(path: Path, *servers: str) -> Path:
    path.write_text(
        json.dumps(
            {
                "apiVersion": "v1",
                "kind": "Config",
                "clusters": [
                    {"name": f"c{i}", "cluster": {"server": s}} for i, s in enumerate(servers)
                ],
                "users": [{"name": "u", "user": {"token": "t"}}],
                "contexts": [{"name": "ctx", "context": {"cluster": "c0", "user": "u"}}],
                "current-context": "ctx",
            }
        )
    )
    return path


@pytest.fixture
def harness_kubeconfig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "kubeconfig"
    monkeypatch.setattr(harness, "KUBECONFIG", path)
    return path


def test_guard_accepts_the_harness_kubeconfig(harness_kubeconfig: Path) -> None:
    _kubeconfig(harness_kubeconfig, "https://127.0.0.1:26443")
    server = guard_kubeconfig(harness_kubeconfig, expected_server="https://127.0.0.1:26443")
    assert server == "https://127.0.0.1:26443"


@pytest.mark.parametrize(
    "server", ["https://10.0.0.1:6443", "https://127.0.0.1:6443", "https://prod.example.com"]
)
def test_guard_refuses_another_api_server(harness_kubeconfig: Path, server: str) -> None:
    _kubeconfig(harness_kubeconfig, server)
    with pytest.raises(UnsafeKubeconfig, match="not the harness's own"):
        guard_kubeconfig(harness_kubeconfig, expected_server="https://127.0.0.1:26443")


def test_guard_refuses_a_file_that_is_not_the_harness_kubeconfig(
    harness_kubeconfig: Path, tmp_path: Path
) -> None:
    other = _kubeconfig(tmp_path / "copy", "https://127.0.0.1:26443")
    with pytest.raises(UnsafeKubeconfig, match="is not the harness kubeconfig"):
        guard_kubeconfig(other, expected_server="https://127.0.0.1:26443")


def test_guard_refuses_a_kubeconfig_with_several_clusters(tmp_path: Path) -> None:
    path = _kubeconfig(tmp_path / "kc", "https://127.0.0.1:16550", "https://prod:6443")
    with pytest.raises(UnsafeKubeconfig, match="exactly one cluster"):
        guard_kubeconfig(path, expected_server=None)


def test_staging_modules_come_from_the_v0_0_0_requires() -> None:
    gomod = """module k8s.io/kubernetes
require (
\tk8s.io/api v0.0.0
\tk8s.io/utils v0.0.0-20260210185600-b8788abfbbc2
\tk8s.io/kubectl v0.0.0
)
require k8s.io/streaming v0.0.0
replace (
\tk8s.io/api => ./staging/src/k8s.io/api
)
"""
    assert gomodule.staging_modules(gomod) == ["k8s.io/api", "k8s.io/kubectl", "k8s.io/streaming"]


def test_generated_nodes_label_like_nodes_yaml() -> None:
    fake, _ = split_manifest(harness.NODES_FILE.read_text())
    fixed = {d["metadata"]["name"]: d for d in fake}
    generated = {n["metadata"]["name"]: n for n in harness.generated_nodes(5, 6, 1)}
    for name, node in generated.items():
        assert node["metadata"]["labels"] == fixed[name]["metadata"]["labels"], name
        assert node["status"] == fixed[name]["status"], name
    assert set(fixed) - set(generated) == {"solo-robot", "solo-edge"}
    # every fake node takes only the pods fogfleet plans, under the key those pods tolerate
    assert all(d["spec"]["taints"] == [SIMULATED_TAINT] for d in fixed.values())
    assert all(n["spec"]["taints"] == [SIMULATED_TAINT] for n in generated.values())
    assert SIMULATED_TAINT["key"] == DEDICATED_TAINT_KEY == PLANNED_TOLERATION["key"]
    assert all(d["metadata"]["annotations"]["kwok.x-k8s.io/node"] == "fake" for d in fake)


def test_nodes_yaml_declares_two_real_robots_and_a_real_edge_node() -> None:
    _, real = split_manifest(harness.NODES_FILE.read_text())
    tiers = sorted(n.labels["fogfleet.io/tier"] for n in real)
    assert tiers == ["edge", "robot", "robot"]
    for node in real:
        assert node.labels["fogfleet.io/e2e-real"] == "true"  # fake-node tests exclude them
        assert 0 < node.cpu_millis < 2000 and node.memory_bytes >= 2**30
        assert node.link["latencyMillis"] >= 0 and node.link["type"] in ("wifi", "lan", "wan")
    assert [n.index for n in real] == [1, 2, 3]
    assert len({n.net.ip for n in real} | {n.net.pod_cidr for n in real}) == 6


def test_a_real_node_without_its_share_is_refused() -> None:
    doc = """
apiVersion: v1
kind: Node
metadata:
  name: r
  annotations: {fogfleet.io/e2e-real: "true", fogfleet.io/e2e-memory: 1Gi}
"""
    with pytest.raises(harness.HarnessError, match=r"real node r: bad or missing .*e2e-cpu"):
        split_manifest(doc)


def test_scrape_targets_must_be_loopback(tmp_path: Path) -> None:
    cluster = harness.Cluster(
        state_dir=tmp_path,
        bin_dir=tmp_path,
        kubeconfig=tmp_path / "kc",
        api_server="https://127.0.0.1:1",
        prometheus_url="http://127.0.0.1:2",
        prometheus_targets_dir=tmp_path / "targets",
        ports={},
    )
    path = cluster.add_prometheus_target("twin", "127.0.0.1:9123", labels={"fleet": "w"})
    assert json.loads(path.read_text()) == [
        {"targets": ["127.0.0.1:9123"], "labels": {"job": "twin", "fleet": "w"}}
    ]
    with pytest.raises(harness.HarnessError, match=r"only 127\.0\.0\.1"):
        cluster.add_prometheus_target("pod", "10.0.0.7:8080")
    cluster.remove_prometheus_target("twin")
    assert not path.exists()


def test_a_cluster_from_state_knows_its_real_nodes_and_versions() -> None:
    state = {"ports": {"kube-apiserver": 1, "prometheus": 2}, "real_nodes": ["bed-robot-1"],
             "versions": {"K8S_VERSION": "1.36.3"}}  # fmt: skip
    cluster = harness.Cluster.from_state(state)
    assert cluster.real_nodes == ("bed-robot-1",) and cluster.versions["K8S_VERSION"] == "1.36.3"


def test_scale_heartbeats_reach_kwok_and_the_controller_manager_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from e2e.bed import heartbeats
    from e2e.bed.cluster import PREFERRED_PORTS
    from e2e.bed.controlplane import Heartbeats, _argv

    bed, scale = _argv(PREFERRED_PORTS), _argv(PREFERRED_PORTS, heartbeats.SCALE)
    assert "--node-lease-duration-seconds=120" in scale["kwok"][0]
    assert "--node-monitor-grace-period=120s" in scale["kube-controller-manager"][0]
    assert f"--node-lease-duration-seconds={Heartbeats().lease_seconds}" in bed["kwok"][0]
    assert {n for n in bed if bed[n][0] != scale[n][0]} == {"kwok", "kube-controller-manager"}
    # the file a relaxed run leaves names what the bed runs with until restored
    monkeypatch.setattr(heartbeats, "_FILE", tmp_path / "heartbeats.json")
    assert heartbeats.current() == Heartbeats()
    (tmp_path / "heartbeats.json").write_text(
        json.dumps({"lease_seconds": 120, "grace_period": "120s"})
    )
    assert heartbeats.current() == heartbeats.SCALE


def test_prometheus_finds_the_real_nodes_pods_through_the_api_as_itself() -> None:
    """kubernetes_sd, one pod list per real node (the watch cache's node index), the bed's pod
    IPs only (kwok's fake pods are never scraped), with Prometheus's own certificate; and the
    labels the operator's queries use."""
    from e2e.bed import clusterservices
    from e2e.bed.cluster import PREFERRED_PORTS
    from e2e.bed.controlplane import FALLBACK_SCRAPE_PROTOCOL, _prometheus_config

    config = _prometheus_config(PREFERRED_PORTS, ["bed-robot-1", "bed-edge-1"])
    jobs = {j["job_name"]: j for j in config["scrape_configs"]}
    pods = jobs["kubernetes-pods"]
    sds = pods["kubernetes_sd_configs"]
    assert [sd["selectors"] for sd in sds] == [
        [{"role": "pod", "field": "spec.nodeName=bed-robot-1"}],
        [{"role": "pod", "field": "spec.nodeName=bed-edge-1"}],
    ]
    assert all(sd["role"] == "pod" and sd["api_server"] == "https://127.0.0.1:26443" for sd in sds)
    assert all(sd["tls_config"]["cert_file"].endswith("/prometheus.crt") for sd in sds)
    keeps = {r["source_labels"][0]: r["regex"] for r in pods["relabel_configs"]
             if r.get("action") == "keep"}  # fmt: skip
    assert keeps["__meta_kubernetes_pod_annotation_prometheus_io_scrape"] == "true"
    ip = re.compile(keeps["__meta_kubernetes_pod_ip"])
    assert ip.fullmatch("198.18.17.4") and ip.fullmatch("198.19.0.7")
    assert not ip.fullmatch("10.0.0.7") and not ip.fullmatch("198.180.0.1")
    targets = {r.get("target_label") for r in pods["relabel_configs"]}
    assert {"namespace", "pod", "node", "__address__", "__metrics_path__"} <= targets
    assert all(j["fallback_scrape_protocol"] == FALLBACK_SCRAPE_PROTOCOL for j in jobs.values())
    # without real nodes nothing lists pods (8000 kwok pods would be listed for nothing)
    assert "kubernetes-pods" not in {
        j["job_name"] for j in _prometheus_config(PREFERRED_PORTS)["scrape_configs"]
    }
    # Prometheus may read pods and nothing else; CoreDNS only what names are made of
    roles = {o["metadata"]["name"]: o for o in clusterservices.RBAC if o["kind"] == "ClusterRole"}
    assert roles["fogfleet-bed:prometheus"]["rules"] == [
        {"apiGroups": [""], "resources": ["pods"], "verbs": ["get", "list", "watch"]}
    ]
    verbs = {v for r in roles["fogfleet-bed:coredns"]["rules"] for v in r["verbs"]}
    assert verbs == {"list", "watch"}


def test_cluster_dns_serves_cluster_local_on_the_bridge_only(tmp_path: Path) -> None:
    """CoreDNS binds the bridge address (never 0.0.0.0), has no forward plugin and serves one
    zone; kubelets point pods at its Service without the host's resolv.conf."""
    from e2e.bed import bednet, clusterservices, gomodule, realnodes
    from e2e.bed.cluster import PREFERRED_PORTS

    text = clusterservices.corefile(PREFERRED_PORTS, tmp_path / "kc")
    assert text.startswith("cluster.local:53 {") and text.count("{") == 2
    assert f"bind {bednet.BRIDGE_IP}\n" in text and "forward" not in text
    assert "forward" not in gomodule.COREDNS_PLUGINS and "kubernetes" in gomodule.COREDNS_PLUGINS
    main = gomodule.coredns_main()
    assert '"github.com/coredns/coredns/core/plugin"' not in main  # not every plugin
    assert all(f'plugin/{p}"' in main for p in gomodule.COREDNS_PLUGINS)
    services = {o["metadata"]["name"]: o for o in clusterservices.service_objects(29090)}
    assert services["kube-dns"]["spec"]["clusterIP"] == bednet.DNS_SERVICE_IP == "198.19.0.10"
    endpoints = services["prometheus-bed"]
    assert endpoints["endpoints"][0]["addresses"] == [bednet.BRIDGE_IP]
    assert endpoints["ports"][0]["port"] == 29090
    node = realnodes.RealNode("n", 1, {}, 400, 2**30)
    kubelet = realnodes._kubelet_config(node, tmp_path, realnodes.Membership("https://x"))
    assert kubelet["clusterDNS"] == [bednet.DNS_SERVICE_IP] and kubelet["resolvConf"] == ""
    assert kubelet["clusterDomain"] == "cluster.local"


def test_prometheus_module_version_follows_the_release() -> None:
    from e2e.bed.gomodule import prometheus_module_version

    assert prometheus_module_version("3.16.0") == "v0.316.0"
    assert prometheus_module_version("3.5.1") == "v0.305.1"


def test_a_long_command_logs_progress_and_writes_its_log_as_it_goes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from e2e.bed import base

    monkeypatch.setattr(base, "PROGRESS_SECONDS", 0.1)
    log_file = tmp_path / "build.log"
    script = f"echo compiling k8s.io/api; sleep 0.35; head -n 2 {log_file} >&2; echo done"
    out = base.run(["sh", "-c", script], log_file=log_file)
    # the log already held the first line while the command still ran (it printed it back)
    assert out.splitlines().count("compiling k8s.io/api") == 2 and out.endswith("done\n")
    progress = [line for line in capsys.readouterr().err.splitlines() if "so far" in line]
    assert len(progress) >= 2
    assert "sh: " in progress[0] and "last output: compiling k8s.io/api" in progress[0]


def test_a_failing_command_names_itself_and_its_output(tmp_path: Path) -> None:
    from e2e.bed import base

    with pytest.raises(harness.HarnessError, match=r"exit 3.*\n.*broken"):
        base.run(["sh", "-c", "echo broken; exit 3"])


def test_down_exits_1_and_names_what_it_could_not_remove(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A cgroup2 tree with something inside that rmdir cannot remove (a busy cgroup on a real
    host; here a file) is left behind on purpose: `down` must say so and exit 1, not 0."""
    from e2e.bed import bed, bednet, cgroups

    v1, v2 = tmp_path / "cpu", tmp_path / "unified"
    planted = v2 / cgroups.TOP / "kubepods" / "pod-1"
    planted.mkdir(parents=True)
    (planted / "cgroup.procs").write_text("")  # rmdir of a non-empty directory fails
    (v1 / cgroups.TOP / "bed-robot-1").mkdir(parents=True)  # removable: down removes it
    mounts = {"cgroup": [v1], "cgroup2": [v2]}
    monkeypatch.setattr(cgroups, "_mounted", lambda fstype: mounts[fstype])
    monkeypatch.setattr(bed, "STATE_DIR", tmp_path / "no-state")
    monkeypatch.setattr(bednet, "teardown", lambda: None)  # the host's links are not ours here
    monkeypatch.setattr(bed, "locked", contextlib.nullcontext)

    assert bed.down() == 1
    err = capsys.readouterr().err
    assert f"left behind: cgroup {v2 / cgroups.TOP}" in err
    assert not (v1 / cgroups.TOP).exists()  # what it could remove, it removed
    assert str(v1 / cgroups.TOP) not in err

    (planted / "cgroup.procs").unlink()
    assert bed.down() == 0 or "cgroup" not in capsys.readouterr().err  # host links may remain
    assert not (v2 / cgroups.TOP).exists()


def test_a_node_fault_signals_only_a_pid_whose_start_time_matches(tmp_path, monkeypatch):
    """nodefaults reads the nodehost's pids.json and trusts a pid only with its start time:
    a recycled pid (another process now) is never signalled."""
    import os
    import subprocess
    import sys

    from e2e.bed import nodefaults, realnodes
    from e2e.bed.base import HarnessError
    from e2e.bed.processes import _proc_starttime

    monkeypatch.setattr(realnodes, "NODES_DIR", tmp_path)
    node = realnodes.RealNode("n", 1, {}, 100, 2**20)
    node.dir.mkdir()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        table = {
            "nodehost": {"pid": os.getpid(), "starttime": _proc_starttime(os.getpid())},
            "kubelet": {"pid": child.pid, "starttime": "1"},  # the pid of another process
            "containerd": {"pid": child.pid, "starttime": _proc_starttime(child.pid)},
        }
        (node.dir / "pids.json").write_text(json.dumps(table))
        assert nodefaults.pids(node) == {"nodehost": os.getpid(), "containerd": child.pid}
        with pytest.raises(HarnessError, match="no running kubelet"):
            nodefaults.restart(node, "kubelet")
        with pytest.raises(HarnessError, match="unknown node component"):
            nodefaults.restart(node, "etcd")
        assert child.poll() is None  # nothing was signalled
    finally:
        child.kill()
        child.wait()


def test_the_bed_module_is_one_per_set_of_releases_and_its_tools_name_it(tmp_path: Path) -> None:
    """The module is remade when a pinned release changes, and a tool built another way (no
    stamp naming this module) is built again; kube-router is built apart, without one."""
    from e2e.bed.tools import Tool, tool_specs

    v = harness.load_versions()
    assert gomodule.module_dir(v) == gomodule.module_dir(dict(v))
    for key in ("K8S_VERSION", "ETCD_VERSION", "COREDNS_VERSION", "GO_MIN_VERSION"):
        assert gomodule.module_dir({**v, key: "9.9.9"}) != gomodule.module_dir(v), key
    specs = tool_specs(v)
    stamped = {n for n, t in specs.items() if t.stamp is not None}
    assert stamped == set(gomodule.MODULE_TOOLS)
    stamp = f"built-from-{gomodule.module_dir(v).name}"
    assert {specs[n].root / stamp for n in stamped} == {specs[n].stamp for n in stamped}
    packages = gomodule._tool_packages(v)
    assert f"k8s.io/kubernetes/cmd/kubelet@v{v['K8S_VERSION']}" in packages
    assert not any("kube-router" in p or "coredns" in p for p in packages)
    binary = tmp_path / "bin" / "tool"
    binary.parent.mkdir()
    binary.write_text("")
    new = tmp_path / "built-from-go-module-new"
    tool = Tool("t", tmp_path, {"tool": binary}, stamp=new)
    (tmp_path / "built-from-go-module-old").write_text("go-module-old\n")
    assert not tool.ok()
    tool.stamp_built()
    assert tool.ok() and list(tmp_path.glob("built-from-*")) == [new]
