"""``fogfleet twin``: the I/O around the pure twin (pods in, metrics out, load control).

Three loops in daemon threads:

* **cluster** (every ``poll_seconds``): lists fogfleet's pods (``app.kubernetes.io/managed-by=
  fogfleet``) in each scenario namespace, the Nodes (for their ``fogfleet.io/tier``) and the
  SoftwareModules (for the pools: service rate, targets, setup times, privacy). It only reads
  the API server; it never contacts a pod, node or Service address.
* **simulation** (every ``step_seconds``): advances each service's :class:`~.model.ServiceSim`
  to now at the scenario's rate and records the results; re-reads the scenario file when it
  changes (the phase clock restarts then).
* **HTTP** on 127.0.0.1 only: ``GET /metrics`` (Prometheus), ``GET /healthz``, ``GET /load``
  (current rates), ``POST /load`` with ``{"module", "namespace", "requestsPerSecond",
  "privateShare"}`` to set a service's rate now (until the next scenario change), or
  ``{"clear": true}`` to drop every override.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import logging
import signal
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Protocol

from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from fogfleet.api.labels import LABEL_MANAGED_BY, LABEL_TIER, MANAGER
from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.autoscaling.policy import Pool
from fogfleet.autoscaling.pools import DISPATCH_RESERVE, pools_for
from fogfleet.errors import FogfleetError

from .exporter import TwinMetrics
from .model import ServiceSim
from .pods import count_replicas
from .scenario import Scenario, Service, load_scenario
from .tally import Tally

__all__ = ["Twin", "TwinKube", "run_twin"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


class TwinKube(Protocol):
    """Read-only API server access (``fogfleet.adapters.kube.KubeClient`` fits)."""

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def list_nodes(self) -> list[Obj]: ...

    def list_modules(self, namespace: str) -> list[Obj]: ...


@dataclass
class _Svc:
    sim: ServiceSim
    pools: tuple[Pool, ...]
    tally: Tally = field(default_factory=Tally)


def _loopback(host: str) -> str:
    if host != "localhost" and not ipaddress.ip_address(host).is_loopback:
        raise ValueError(f"the twin listens on loopback only, not {host}")
    return host


class Twin:
    def __init__(
        self,
        kube: TwinKube,
        scenario_path: str | Path,
        *,
        port: int = 9123,
        host: str = "127.0.0.1",
        namespace: str = "default",
        step_seconds: float = 0.2,
        poll_seconds: float = 1.0,
        seed: int = 0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.kube = kube
        self.scenario_path = Path(scenario_path)
        self.namespace = namespace
        self.step_seconds = step_seconds
        self.poll_seconds = poll_seconds
        self.seed = seed
        self.clock = clock
        self.metrics = TwinMetrics()
        self.scenario: Scenario = load_scenario(self.scenario_path, namespace)
        self._mtime = self._stat()
        self._origin = clock()
        self._overrides: dict[tuple[str, str], tuple[float, float | None]] = {}
        self._services: dict[tuple[str, str], _Svc] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._server = ThreadingHTTPServer((_loopback(host), port), self._handler())
        self._server.daemon_threads = True

    @property
    def port(self) -> int:
        return int(self._server.server_address[1])

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Twin:
        for target, name in (
            (self._server.serve_forever, "twin-http"),
            (self._poll_loop, "twin-cluster"),
            (self._sim_loop, "twin-sim"),
        ):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        log.info("Started the twin on 127.0.0.1:%d for %d services", self.port,
                 len(self.scenario.services))  # fmt: skip
        return self

    def stop(self) -> None:
        self._stop.set()
        self._server.shutdown()
        self._server.server_close()
        for thread in self._threads:
            thread.join(timeout=5)

    # ------------------------------------------------------------------ load
    def set_load(
        self, namespace: str, module: str, rate: float, private_share: float | None = None
    ) -> None:
        if rate < 0 or (private_share is not None and not 0 <= private_share <= 1):
            raise ValueError("requestsPerSecond >= 0 and 0 <= privateShare <= 1")
        with self._lock:
            self._overrides[(namespace, module)] = (rate, private_share)

    def tally(self, namespace: str, module: str) -> Tally:
        """What the service's requests met so far (all zero before the twin simulates it)."""
        with self._lock:
            state = self._services.get((namespace, module))
            return state.tally if state is not None else Tally()

    def clear_load(self) -> None:
        with self._lock:
            self._overrides.clear()

    def rates(self, service: Service, now: float) -> tuple[float, float]:
        """(private, normal) requests/s of a service now."""
        rate, share = service.rate_at(now - self._origin), service.private_share
        override = self._overrides.get(service.key)
        if override is not None:
            rate = override[0]
            share = share if override[1] is None else override[1]
        return rate * share, rate * (1.0 - share)

    # ------------------------------------------------------------------ loops
    def _stat(self) -> float:
        try:
            return self.scenario_path.stat().st_mtime
        except OSError:
            return 0.0

    def _reload_if_changed(self) -> None:
        mtime = self._stat()
        if mtime == self._mtime:
            return
        self._mtime = mtime
        try:
            scenario = load_scenario(self.scenario_path, self.namespace)
        except FogfleetError as exc:
            log.warning("Kept the previous scenario: %s", exc)
            return
        with self._lock:
            self.scenario = scenario
            self._origin = self.clock()
            self._overrides.clear()
        log.info("Reloaded the scenario %s", self.scenario_path)

    def poll_once(self) -> None:
        """Read pods, nodes and modules; update each service's replicas."""
        scenario = self.scenario
        nodes = {
            n["metadata"]["name"]: (n["metadata"].get("labels") or {}).get(LABEL_TIER, "")
            for n in self.kube.list_nodes()
        }
        pods: list[Obj] = []
        setup: dict[tuple[str, str, str], float] = {}
        for ns in sorted({s.namespace for s in scenario.services}):
            pods += self.kube.list_pods(ns, {LABEL_MANAGED_BY: MANAGER})
            modules = {m["metadata"]["name"]: m for m in self.kube.list_modules(ns)}
            for svc in scenario.services:
                if svc.namespace == ns and svc.module in modules:
                    self._configure(svc, modules[svc.module])
                    for pool in self._services[svc.key].pools:
                        setup[(ns, svc.module, pool.name)] = pool.setup_seconds
        counts = count_replicas(pods, nodes, setup, self.clock())
        with self._lock:
            for key, state in self._services.items():
                tiers = counts.get(key, {})
                for pool in state.pools:
                    ready, starting = tiers.get(pool.name, (0, 0))
                    if pool.name == "all":
                        ready = sum(r for r, _ in tiers.values())
                        starting = sum(s for _, s in tiers.values())
                    state.sim.set_replicas(pool.name, ready, starting)

    def _configure(self, service: Service, body: Obj) -> None:
        try:
            mod = parse_object({k: v for k, v in body.items() if k != "status"})
        except FogfleetError as exc:
            log.warning("Skipped %s/%s: %s", service.namespace, service.module, exc)
            return
        if not isinstance(mod, SoftwareModule) or mod.spec.scaling is None:
            return
        pools = tuple(pools_for(mod))
        with self._lock:
            have = self._services.get(service.key)
            if have is None:
                sim = ServiceSim(pools, seed=self.seed, reserve=DISPATCH_RESERVE)
                sim.now = self.clock() - self._origin
                self._services[service.key] = _Svc(sim, pools)
                self.metrics.declare(service.namespace, service.module, [p.name for p in pools])
            elif have.pools != pools:
                have.sim.reconfigure(pools)
                have.pools = pools

    def step_once(self) -> None:
        """Advance every simulated service to now and export what happened."""
        self._reload_if_changed()
        now = self.clock()
        with self._lock:
            for svc in self.scenario.services:
                state = self._services.get(svc.key)
                if state is None:
                    continue
                private, normal = self.rates(svc, now)
                records = state.sim.advance(now - self._origin, private, normal)
                self.metrics.record(svc.namespace, svc.module, records)
                state.tally = state.tally.add(records)
                for pool in state.pools:
                    ready, starting = state.sim.replicas(pool.name)
                    self.metrics.pool(svc.namespace, svc.module, pool.name, ready, starting,
                                      state.sim.queue_length(pool.name))  # fmt: skip

    def _poll_loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.poll_once()
            except FogfleetError as exc:
                log.warning("Kept the last replica counts: %s", exc)
            except Exception:  # a bug must not kill the exporter silently
                log.exception("Failed to read the cluster")
            self._stop.wait(self.poll_seconds)

    def _sim_loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.step_once()
            except Exception:
                log.exception("Failed a simulation step")
            self._stop.wait(self.step_seconds)

    # ------------------------------------------------------------------ HTTP
    def _handler(self) -> type[BaseHTTPRequestHandler]:
        twin = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, format: str, *args: Any) -> None:
                log.debug("twin http: " + format, *args)

            def _send(self, code: int, body: bytes, ctype: str = "application/json") -> None:
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                if self.path.startswith("/metrics"):
                    self._send(200, generate_latest(twin.metrics.registry), CONTENT_TYPE_LATEST)
                elif self.path == "/healthz":
                    self._send(200, b"ok", "text/plain")
                elif self.path == "/load":
                    now = twin.clock()
                    with twin._lock:
                        data = {
                            f"{s.namespace}/{s.module}": dict(
                                zip(("private", "normal"), twin.rates(s, now), strict=True)
                            )
                            for s in twin.scenario.services
                        }
                    self._send(200, json.dumps(data).encode())
                else:
                    self._send(404, b'{"error": "not found"}')

            def do_POST(self) -> None:
                if self.path != "/load":
                    self._send(404, b'{"error": "not found"}')
                    return
                try:
                    length = int(self.headers.get("Content-Length", "0"))
                    body = json.loads(self.rfile.read(length) or b"{}")
                    if body.get("clear"):
                        twin.clear_load()
                    else:
                        twin.set_load(
                            str(body.get("namespace") or twin.namespace),
                            str(body["module"]),
                            float(body["requestsPerSecond"]),
                            None if body.get("privateShare") is None
                            else float(body["privateShare"]),
                        )  # fmt: skip
                except (ValueError, KeyError, TypeError, AttributeError) as exc:
                    self._send(400, json.dumps({"error": str(exc)}).encode())
                    return
                self._send(200, b'{"ok": true}')

        return Handler


def run_twin(args: Any) -> int:
    """CLI hook: ``fogfleet twin --scenario FILE [--port 9123] [--namespace NS]
    [--kubeconfig PATH]``; runs until SIGINT/SIGTERM. Raises InvalidSpec for a bad scenario."""
    from fogfleet.adapters.kube import KubeClient, load_config

    kube = KubeClient(load_config(getattr(args, "kubeconfig", None)))
    twin = Twin(
        kube,
        args.scenario,
        port=int(getattr(args, "port", None) or 9123),
        namespace=getattr(args, "namespace", None) or "default",
    ).start()
    print(f"fogfleet twin: serving metrics on http://127.0.0.1:{twin.port}/metrics", flush=True)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # not the main thread
            signal.signal(sig, lambda *_: done.set())
    done.wait()
    twin.stop()
    return 0
