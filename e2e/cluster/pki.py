"""The bed's PKI: one CA; the admin, apiserver-serving and per-node kubelet certificates."""

from __future__ import annotations

import base64
import json
from pathlib import Path

from e2e.cluster.base import KUBECONFIG, STATE_DIR, run


def _openssl(*args: str | Path) -> None:
    run(["openssl", *args], cwd=STATE_DIR / "pki", hint="hint: openssl is needed for the PKI")


def _make_pki() -> None:
    pki = STATE_DIR / "pki"
    pki.mkdir(parents=True, exist_ok=True)
    _openssl(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "3650",
        "-subj",
        "/CN=fogfleet-e2e-ca",
        "-keyout",
        "ca.key",
        "-out",
        "ca.crt",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign,cRLSign,digitalSignature",
    )
    _openssl(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-subj",
        "/O=system:masters/CN=fogfleet-e2e-admin",
        "-keyout",
        "admin.key",
        "-out",
        "admin.csr",
    )
    (pki / "ext.cnf").write_text(
        "subjectAltName=IP:127.0.0.1,DNS:localhost,DNS:kubernetes,DNS:kubernetes.default,"
        "DNS:kubernetes.default.svc,DNS:kubernetes.default.svc.cluster.local\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        "keyUsage=critical,digitalSignature,keyEncipherment\n"
        "basicConstraints=CA:FALSE\n"
    )
    _openssl(
        "x509",
        "-req",
        "-in",
        "admin.csr",
        "-CA",
        "ca.crt",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-days",
        "3650",
        "-extfile",
        "ext.cnf",
        "-out",
        "admin.crt",
    )
    _openssl("genrsa", "-out", "sa.key", "2048")
    for key in pki.glob("*.key"):
        key.chmod(0o600)


def _b64(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def _write_kubeconfig(api_server: str) -> None:
    pki = STATE_DIR / "pki"
    cfg = {
        "apiVersion": "v1",
        "kind": "Config",
        "clusters": [
            {
                "name": "fogfleet-e2e",
                "cluster": {
                    "server": api_server,
                    "certificate-authority-data": _b64(pki / "ca.crt"),
                },
            }
        ],
        "users": [
            {
                "name": "fogfleet-e2e-admin",
                "user": {
                    "client-certificate-data": _b64(pki / "admin.crt"),
                    "client-key-data": _b64(pki / "admin.key"),
                },
            }
        ],
        "contexts": [
            {
                "name": "fogfleet-e2e",
                "context": {"cluster": "fogfleet-e2e", "user": "fogfleet-e2e-admin"},
            }
        ],
        "current-context": "fogfleet-e2e",
    }
    KUBECONFIG.write_text(json.dumps(cfg, indent=1) + "\n")  # JSON is valid YAML
    KUBECONFIG.chmod(0o600)
