#!/usr/bin/env python3
"""Pod service discovery for the bed's Prometheus (stdlib only).

Debian's Prometheus 2.42 is built without ``kubernetes_sd_configs``, so this process plays its
role: every two seconds it lists the pods annotated ``prometheus.io/scrape: "true"`` that run
on real nodes (pod IP inside the bed's 198.18.0.0/15) and writes them as a file_sd target file
with the labels kubernetes_sd's usual relabelling gives: ``namespace``, ``pod``, ``node`` and
``job="kubernetes-pods"``; ``prometheus.io/port`` and ``prometheus.io/path`` are honoured.
kwok's fake pods never become targets (their addresses lead nowhere).

Given the real nodes' names it lists only their pods, one node at a time (the API server's
watch cache indexes pods by ``spec.nodeName``); every list reads that cache
(``resourceVersion=0``), not etcd. Listing every Running pod from etcd every two seconds cost
this process alone 0.1-0.4 of a core at 8000 kwok pods (2026-11-26, bench scale at 1000
robots), besides the API server's reads, on the same two cores the cluster under test runs on.

    python3 e2e/bed/poddiscovery.py STATE_DIR API_SERVER TARGET_FILE [NODE ...]
"""

from __future__ import annotations

import ipaddress
import json
import signal
import ssl
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

BED = ipaddress.ip_network("198.18.0.0/15")
INTERVAL = 2.0


def targets(pods: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for pod in pods.get("items", []):
        meta, status = pod.get("metadata", {}), pod.get("status", {})
        ann = meta.get("annotations") or {}
        ip = status.get("podIP")
        if ann.get("prometheus.io/scrape") != "true" or not ip or status.get("phase") != "Running":
            continue
        if ipaddress.ip_address(ip) not in BED:
            continue
        labels = {
            "job": "kubernetes-pods",
            "namespace": meta.get("namespace", ""),
            "pod": meta.get("name", ""),
            "node": pod.get("spec", {}).get("nodeName", ""),
        }
        if path := ann.get("prometheus.io/path"):
            labels["__metrics_path__"] = path
        port = ann.get("prometheus.io/port", "9100")
        out.append({"targets": [f"{ip}:{port}"], "labels": labels})
    return sorted(out, key=lambda t: t["targets"][0])


def list_urls(api_server: str, nodes: list[str]) -> list[str]:
    """One pod list per real node (all Running pods when no node is named), from the watch
    cache."""
    running = "status.phase=Running"
    selectors = [f"spec.nodeName={n},{running}" for n in nodes] or [running]
    return [
        f"{api_server}/api/v1/pods?"
        + urllib.parse.urlencode({"resourceVersion": "0", "fieldSelector": sel})
        for sel in selectors
    ]


def main(state_dir: str, api_server: str, target_file: str, *nodes: str) -> int:
    pki = Path(state_dir) / "pki"
    ctx = ssl.create_default_context(cafile=str(pki / "ca.crt"))
    ctx.load_cert_chain(str(pki / "admin.crt"), str(pki / "admin.key"))
    urls = list_urls(api_server, list(nodes))
    out = Path(target_file)
    running = True

    def stop(*_: object) -> None:
        nonlocal running
        running = False

    signal.signal(signal.SIGTERM, stop)
    last = None
    while running:
        try:
            found = []
            for url in urls:
                with urllib.request.urlopen(url, context=ctx, timeout=10) as resp:
                    found += targets(json.loads(resp.read()))
            found.sort(key=lambda t: t["targets"][0])
        except (OSError, ValueError) as exc:
            print(f"poddiscovery: {exc}", file=sys.stderr, flush=True)
        else:
            text = json.dumps(found, indent=1) + "\n"
            if text != last:
                tmp = out.with_name(f".{out.name}.tmp")
                tmp.write_text(text)
                tmp.replace(out)
                last = text
        time.sleep(INTERVAL)
    out.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
