"""Composition root of the operator: Settings -> adapters -> controller runtime -> kopf.

``fogfleet run`` calls :func:`run`. Tests call :func:`run` in a thread with a ``stop_flag``.
"""

from __future__ import annotations

import asyncio
import http.server
import logging
import signal
import threading
from typing import Any

import kopf

from fogfleet.adapters.hub import hub_client
from fogfleet.adapters.kube import KubeClient, load_config
from fogfleet.adapters.leases import LeaseLock, LeaseSettings
from fogfleet.adapters.metrics import PrometheusMetrics
from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.adapters.watched import WatchedKube
from fogfleet.controllers.deps import Deps, Hub
from fogfleet.controllers.measure.links import LinkDeps
from fogfleet.controllers.measure.observed import ObservedDeps
from fogfleet.controllers.module.scaling import ScalingDeps
from fogfleet.controllers.monitoring import MonitoredPrometheus, Monitoring
from fogfleet.runtime.dispatch import Runtime
from fogfleet.runtime.handlers import register
from fogfleet.settings import Settings

__all__ = ["build_runtime", "run"]

log = logging.getLogger("fogfleet")
FORMATS = {"plain": kopf.LogFormat.PLAIN, "full": kopf.LogFormat.FULL, "json": kopf.LogFormat.JSON}


def build_runtime(settings: Settings, *, serve_metrics: bool = True) -> Runtime:
    """Adapters and the controller runtime, from settings (no kopf here)."""
    api = load_config(settings.kubeconfig)
    metrics = PrometheusMetrics()
    watched = (
        WatchedKube(api, namespaces=settings.namespaces, metrics=metrics)
        if settings.watch_cache
        else None
    )
    kube = watched or KubeClient(api, metrics=metrics)
    if serve_metrics and settings.metrics_port:
        metrics.serve(settings.metrics_port, settings.metrics_host)
    deps = Deps(
        kube=kube,
        metrics=metrics,
        scheduler_defaults=settings.scheduler_defaults(),
        api_concurrency=settings.api_concurrency,
        watches=watched,
        monitoring=Monitoring(settings.prometheus_url),
        hub=_hub(settings, metrics),
    )
    return Runtime(deps, workers=settings.workers, debounce=settings.debounce_seconds)


def _hub(settings: Settings, metrics: PrometheusMetrics) -> Hub | None:
    """The OCM hub, when the operator has one (docs/multicluster.md)."""
    if not settings.hub_kubeconfig or not settings.cluster_name:
        return None
    log.info("Managed clusters are reached through the OCM hub as %s", settings.cluster_name)
    port = hub_client(settings.hub_kubeconfig, metrics)
    router = settings.site_router or ""
    return Hub(port, settings.cluster_name, tuple(settings.namespaces), router=router)


def _standby_health(settings: Settings) -> http.server.HTTPServer | None:
    """Answer the liveness probe while waiting for the Lease (kopf serves it once leader)."""
    if not settings.liveness_port:
        return None

    class Healthz(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(200 if self.path == "/healthz" else 404)
            self.end_headers()
            self.wfile.write(b"standby\n")

        def log_message(self, *_: Any) -> None:
            return

    http.server.HTTPServer.allow_reuse_address = True
    server = http.server.HTTPServer((settings.liveness_host, settings.liveness_port), Healthz)
    threading.Thread(target=server.serve_forever, name="fogfleet-standby", daemon=True).start()
    return server


def _lead(settings: Settings, stop: threading.Event) -> LeaseLock | None:
    """Block until this replica holds the Lease; None when stopped first."""
    lock = LeaseLock(
        load_config(settings.kubeconfig),
        LeaseSettings(
            namespace=settings.leader_election_namespace,
            name=settings.leader_election_lease,
            identity=settings.leader_election_identity,
            lease_seconds=settings.lease_seconds,
        ),
    )
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    health = _standby_health(settings)
    try:
        return lock if lock.acquire(stop) else None
    finally:
        if health is not None:
            health.shutdown()
            health.server_close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run(
    settings: Settings,
    *,
    stop_flag: threading.Event | None = None,
    ready_flag: threading.Event | None = None,
) -> None:
    """Run the operator until stopped (SIGINT/SIGTERM, or ``stop_flag`` when given).

    With leader election, wait as a standby until this replica holds the Lease, and stop
    reconciling at once if the Lease is lost (the container then restarts as a standby).
    """
    if not settings.leader_election:
        _run_kopf(settings, stop_flag=stop_flag, ready_flag=ready_flag)
        return
    stop = stop_flag or threading.Event()
    lock = _lead(settings, stop)
    if lock is None:
        return
    renewing = threading.Event()
    lock.hold(renewing, on_lost=stop.set)
    try:
        _run_kopf(settings, stop_flag=stop, ready_flag=ready_flag, set_on_exit=stop)
    finally:
        renewing.set()
        lock.release()


def _run_kopf(
    settings: Settings,
    *,
    stop_flag: threading.Event | None,
    ready_flag: threading.Event | None,
    set_on_exit: threading.Event | None = None,
) -> None:
    kopf.configure(
        debug=settings.log_level == "DEBUG",
        verbose=settings.log_level == "DEBUG",
        quiet=settings.log_level in ("WARNING", "ERROR"),
        log_format=FORMATS[settings.log_format],
    )
    logging.getLogger("fogfleet").setLevel(settings.log_level)
    runtime = build_runtime(settings)
    registry = register(kopf.OperatorRegistry(), settings)
    if set_on_exit is not None:
        # kopf waits for a threading.Event stop flag in an executor thread and, when a signal
        # stops it instead, waits for that thread on exit: release it as the operator exits.
        def release_stop_flag(**_: Any) -> None:
            set_on_exit.set()

        kopf.on.cleanup(registry=registry)(release_stop_flag)
    liveness = (
        f"http://{settings.liveness_host}:{settings.liveness_port}/healthz"
        if settings.liveness_port
        else None
    )
    kwargs: dict[str, Any] = (
        {"namespaces": settings.namespaces} if settings.namespaces else {"clusterwide": True}
    )
    log.info("Starting fogfleet (namespaces: %s)", ", ".join(settings.namespaces) or "all")
    if threading.current_thread() is not threading.main_thread():
        asyncio.set_event_loop(asyncio.new_event_loop())
    memo = kopf.Memo(runtime=runtime, settings=settings)
    if settings.prometheus_url:
        # every query tells the fleets' Monitored condition whether Prometheus answers
        prometheus = MonitoredPrometheus(
            PrometheusClient(settings.prometheus_url), runtime.deps.monitoring
        )
        memo.scaling = ScalingDeps(
            runtime.deps.kube,
            prometheus,
            period_seconds=settings.scaling_interval_seconds,
            rate_window_seconds=settings.rate_window_seconds,
        )
        memo.links = LinkDeps(
            prometheus,
            node_label=settings.link_node_label,
            period_seconds=settings.link_interval_seconds,
        )
        memo.observed = ObservedDeps(prometheus, period_seconds=settings.observe_interval_seconds)
    else:
        log.info(
            "Scaling, link monitoring, learnt profiles and drift detection are off: "
            "FOGFLEET_PROMETHEUS_URL is not set (every fleet's Monitored condition says so)"
        )
    kopf.run(
        registry=registry,
        memo=memo,
        standalone=settings.standalone,
        peering_name=None if settings.standalone else settings.peering_name,
        liveness_endpoint=liveness,
        stop_flag=stop_flag,
        ready_flag=ready_flag,
        **kwargs,
    )
