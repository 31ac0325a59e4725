"""Fast checks of the cloud cluster and OCM's part of the bed (no cluster, no network)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from e2e.bed import base, bednet, cloud, ocm, realnodes, routers, tools


def _listen_addresses(argv: list[str]) -> list[str]:
    """Where a process listens, by its flags (a Zenoh endpoint without its ``tcp/``; a WAN
    route's listening side); a Zenoh router's ``--connect`` too, which must stay on loopback."""
    flags = ("--bind-address=", "--listen=", "--advertise-address=", "--server-address=",
             "--connect=")  # fmt: skip
    found = [a.split("=", 1)[1].removeprefix("tcp/") for a in argv if a.startswith(flags)]
    found += [a.split("=")[1] for a in argv if a.startswith("--route=")]
    return found


def test_the_cloud_control_plane_listens_on_loopback_and_stores_apart_from_the_site(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(cloud, "bridge_exists", lambda: True)
    ports = {name: 40000 + i for i, name in enumerate((*cloud.COMPONENTS, cloud.WAN_ZENOH))}
    argv = cloud._argv(ports, "http://127.0.0.1:2379", f"{cloud.ETCD_PREFIX}/1")
    for name, args in argv.items():
        addresses = _listen_addresses(args)
        # the routers also listen on the bed's bridge, for the relays in the pods (the site's
        # real nodes', and the cloud's real node's)
        if name in (cloud.SITE_ROUTER, cloud.CLOUD_ROUTER):
            bridge = f"{bednet.BRIDGE_IP}:{ports[name]}"
            assert bridge in addresses and routers.BRIDGE_ENDPOINT + str(ports[name]) == (
                f"tcp/{bridge}"
            )
            addresses.remove(bridge)
        assert addresses and all(a.startswith("127.0.0.1") for a in addresses), name
    # the site reaches the cloud's API and router only across the WAN
    assert argv[cloud.SITE_ROUTER][-1] == f"--connect=tcp/127.0.0.1:{ports[cloud.WAN_ZENOH]}"
    routes = [a.removeprefix("--route=") for a in argv[cloud.WAN] if a.startswith("--route=")]
    assert routes == [
        f"127.0.0.1:{ports[cloud.WAN]}=127.0.0.1:{ports[cloud.APISERVER]}",
        f"127.0.0.1:{ports[cloud.WAN_ZENOH]}=127.0.0.1:{ports[cloud.CLOUD_ROUTER]}",
    ]
    api = argv[cloud.APISERVER]
    assert f"--etcd-prefix={cloud.ETCD_PREFIX}/1" in api and cloud.ETCD_PREFIX != "/registry"
    # its own CA: nothing the site's CA signed is trusted by the cloud's API
    assert f"--client-ca-file={cloud.PKI / 'ca.crt'}" in api
    assert not any("/cluster/pki/" in a for a in api)


def test_every_ocm_process_listens_on_loopback_without_leader_election(tmp_path: Path) -> None:
    c = cloud.CloudCluster("https://127.0.0.1:1", tmp_path / "cloud.kubeconfig", {})
    managed = {"site": tmp_path / "site.kubeconfig", "cloud": c.kubeconfig}
    names = [ocm.HUB, *(ocm.agent_name(m) for m in managed)]
    boot = {m: tmp_path / f"bootstrap-{m}" for m in managed}
    argv = ocm._argv(c, managed, boot, {n: 41000 + i for i, n in enumerate(names)})
    assert sorted(argv) == sorted(names)
    for name, args in argv.items():
        assert _listen_addresses(args) and all(
            a.startswith("127.0.0.1:") for a in _listen_addresses(args)
        ), name
        assert "--disable-leader-election" in args, name
    site = argv[ocm.agent_name("site")]
    assert "--cluster-name=site" in site
    assert f"--spoke-kubeconfig={managed['site']}" in site
    assert f"--bootstrap-kubeconfig={boot['site']}" in site


def test_ocm_is_built_for_the_cloud_only_and_checked_by_its_version() -> None:
    v = base.load_versions()
    spec = tools.tool_specs(v)["ocm"]
    assert "ocm" not in tools.TOOLS and "ocm" in tools.CLOUD_TOOLS
    assert sorted(spec.binaries) == sorted(ocm.COMMANDS)
    assert all(expect == f"version v{v['OCM_VERSION']}" for _, _, expect in spec.checks)
    # the manifests it installs come with the build, and a build without them is not done
    assert {p.name for p in spec.files} == {"hub-crds", "managed-crds", "bootstrap"}


def test_a_fatal_probe_error_ends_the_wait_at_once() -> None:
    class Gone(base.HarnessError):
        pass

    calls = []

    def probe() -> bool:
        calls.append(1)
        if len(calls) == 1:
            raise ValueError("not yet")  # an ordinary probe failure: try again
        raise Gone("the process exited")

    with pytest.raises(Gone):
        base.wait_for("a process", probe, timeout=30, interval=0.0, fatal=(Gone,))
    assert len(calls) == 2


def test_the_clouds_real_node_joins_the_cloud_with_its_own_ca_and_runs_the_kubelet_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    node, pki = cloud.NODE, tmp_path / "cloud-pki"
    pki.mkdir()
    (pki / "ca.crt").write_text("the cloud's CA")
    member = realnodes.Membership("https://198.18.0.1:40000", pki, services=False)
    kubelet = realnodes._kubelet_config(node, tmp_path, member)
    assert kubelet["authentication"]["x509"]["clientCAFile"] == str(pki / "ca.crt")
    assert kubelet["clusterDNS"] == []  # the site's DNS is not the cloud's
    site = realnodes._kubelet_config(node, tmp_path, realnodes.Membership("https://x"))
    assert site["clusterDNS"] == [bednet.DNS_SERVICE_IP]
    issued: list[Path] = []

    def issue(
        name: str, subject: str, sans: list[str], usage: str = "", pki: Path = Path()
    ) -> Path:
        issued.append(pki)
        cert = tmp_path / f"{name}.crt"
        cert.write_text("")
        cert.with_suffix(".key").write_text("")
        return cert

    monkeypatch.setattr(realnodes, "issue_cert", issue)
    monkeypatch.setattr(realnodes.RealNode, "dir", property(lambda n: tmp_path / n.name))
    cfg = json.loads(realnodes._write_node_files(node, member).read_text())
    assert issued == [pki, pki]  # its serving and client certificates: the cloud's CA signs
    assert sorted(cfg["processes"]) == ["containerd", "kubelet"]
    kubeconfig = (tmp_path / node.name / "kubelet.kubeconfig").read_text()
    assert "https://198.18.0.1:40000" in kubeconfig
    # on the bridge apart from every site profile's nodes
    site_nodes = [n for p in realnodes.PROFILES for n in realnodes.profile_nodes(p)]
    assert node.net.ip not in {n.net.ip for n in site_nodes}
    assert node.net.pod_cidr not in {n.net.pod_cidr for n in site_nodes}
