"""The bed's PKI: one CA; the admin, apiserver-serving and per-node kubelet certificates, and
client certificates of their own for kube-proxy, kube-router, Prometheus and CoreDNS."""

from __future__ import annotations

import base64
import json
from functools import partial
from pathlib import Path

from e2e.bed.base import HOST, KUBECONFIG, STATE_DIR, run
from e2e.bed.bednet import BRIDGE_IP, KUBERNETES_SERVICE_IP

PKI_DIR = STATE_DIR / "pki"


def _openssl(*args: str | Path, pki: Path = PKI_DIR) -> None:
    run(["openssl", *args], cwd=pki, hint="hint: openssl is needed for the PKI")


def issue_cert(
    name: str,
    subject: str,
    sans: list[str],
    usage: str = "serverAuth,clientAuth",
    pki: Path = PKI_DIR,
) -> Path:
    """Sign `<name>.crt` (+ `<name>.key`) with the CA in ``pki`` (the bed's); returns the
    certificate's path."""
    openssl = partial(_openssl, pki=pki)
    openssl(
        "req", "-newkey", "rsa:2048", "-nodes", "-subj", subject,
        "-keyout", f"{name}.key", "-out", f"{name}.csr",
    )  # fmt: skip
    ext = pki / f"{name}.ext"
    lines = [f"subjectAltName={','.join(sans)}"] if sans else []
    lines += [
        f"extendedKeyUsage={usage}",
        "keyUsage=critical,digitalSignature,keyEncipherment",
        "basicConstraints=CA:FALSE",
    ]
    ext.write_text("\n".join(lines) + "\n")
    openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "3650", "-extfile", ext.name, "-out", f"{name}.crt",
    )  # fmt: skip
    (pki / f"{name}.key").chmod(0o600)
    return pki / f"{name}.crt"


def make_ca(pki: Path, name: str) -> None:
    """A CA of its own in ``pki``, and a service-account signing key beside it."""
    pki.mkdir(parents=True, exist_ok=True)
    _openssl(
        "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "3650",
        "-subj", f"/CN={name}", "-keyout", "ca.key", "-out", "ca.crt",
        "-addext", "basicConstraints=critical,CA:TRUE",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign,digitalSignature",
        pki=pki,
    )  # fmt: skip
    _openssl("genrsa", "-out", "sa.key", "2048", pki=pki)
    for key in pki.glob("*.key"):
        key.chmod(0o600)


def _make_pki() -> None:
    """The CA, the admin certificate (also the apiserver's serving certificate) and the SA key.

    The serving names include the bed bridge's address and the `kubernetes` Service's IP, so
    kubelets on real nodes and in-cluster clients verify the apiserver.
    """
    pki = PKI_DIR
    make_ca(pki, "fogfleet-e2e-ca")
    sans = [f"IP:{ip}" for ip in (HOST, BRIDGE_IP, KUBERNETES_SERVICE_IP)] + [
        f"DNS:{d}"
        for d in (
            "localhost",
            "kubernetes",
            "kubernetes.default",
            "kubernetes.default.svc",
            "kubernetes.default.svc.cluster.local",
        )
    ]
    issue_cert("admin", "/O=system:masters/CN=fogfleet-e2e-admin", sans)
    issue_cert("kube-proxy", "/CN=system:kube-proxy", [], usage="clientAuth")
    issue_cert("kube-router", "/CN=system:kube-router", [], usage="clientAuth")
    # Prometheus (kubernetes_sd) and CoreDNS read the API as themselves (clusterservices.RBAC)
    issue_cert("prometheus", "/CN=system:prometheus", [], usage="clientAuth")
    issue_cert("coredns", "/CN=system:coredns", [], usage="clientAuth")


def _b64(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def kubeconfig(
    api_server: str, user: str, cert: Path, key: Path, ca: Path = PKI_DIR / "ca.crt"
) -> str:
    """A kubeconfig (JSON, which is valid YAML) for `user` with an embedded client cert."""
    cfg = {
        "apiVersion": "v1",
        "kind": "Config",
        "clusters": [
            {
                "name": "fogfleet-e2e",
                "cluster": {"server": api_server, "certificate-authority-data": _b64(ca)},
            }
        ],
        "users": [
            {
                "name": user,
                "user": {"client-certificate-data": _b64(cert), "client-key-data": _b64(key)},
            }
        ],
        "contexts": [
            {"name": "fogfleet-e2e", "context": {"cluster": "fogfleet-e2e", "user": user}}
        ],
        "current-context": "fogfleet-e2e",
    }
    return json.dumps(cfg, indent=1) + "\n"


def _write_kubeconfig(api_server: str) -> None:
    pki = STATE_DIR / "pki"
    KUBECONFIG.write_text(
        kubeconfig(api_server, "fogfleet-e2e-admin", pki / "admin.crt", pki / "admin.key")
    )
    KUBECONFIG.chmod(0o600)
