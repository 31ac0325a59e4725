"""Leader election on a coordination.k8s.io Lease, so two operator replicas never both reconcile.

kopf's own peering pauses *every* operator when two have the same priority, which is what two
replicas of one Deployment are; client-go's leader election (a Lease per component, renewed by
the holder, taken over when it expires) is what Kubernetes' own controllers use. This is the
same protocol:

* the holder renews ``spec.renewTime`` every ``renew_seconds``;
* a candidate takes the Lease when it has no holder or its ``renewTime`` is older than
  ``leaseDurationSeconds``; every write carries the ``resourceVersion`` it read, so two
  candidates cannot both win (the API server answers 409 to the loser);
* a holder that cannot renew within the lease duration stops (it may no longer be leader).

Failover after the holder dies therefore takes at most ``lease_seconds + retry_seconds``.
Verbs: coordination.k8s.io leases get create update, in the operator's namespace.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from kubernetes import client
from kubernetes.client.exceptions import ApiException

from fogfleet.adapters.kube import map_errors
from fogfleet.errors import DependencyUnavailable

__all__ = ["LeaseLock", "LeaseSettings"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LeaseSettings:
    namespace: str
    name: str
    identity: str
    lease_seconds: int = 15
    renew_seconds: float = 5.0
    retry_seconds: float = 2.0


def _now() -> datetime:
    return datetime.now(UTC)


class LeaseLock:
    """Acquire, hold and release one Lease (blocking calls; run them off the event loop)."""

    def __init__(self, api: client.ApiClient, settings: LeaseSettings) -> None:
        self._api = client.CoordinationV1Api(api)
        self.settings = settings

    # -- one attempt ------------------------------------------------------------------------

    def try_acquire(self) -> bool:
        """One attempt to become (or stay) the holder; True when this identity holds it now."""
        s = self.settings
        try:
            lease = self._api.read_namespaced_lease(s.name, s.namespace)
        except ApiException as exc:
            if exc.status != 404:
                with map_errors(f"read Lease {s.namespace}/{s.name}"):
                    raise
            return self._create()
        spec = lease.spec or client.V1LeaseSpec()
        held_by_other = spec.holder_identity not in (None, "", s.identity)
        if held_by_other and not self._expired(spec):
            return False
        now = _now()
        # a new holder (after another, or after a release left it empty) is a transition and
        # acquires now, as client-go's leaderelection records it; only a renewal keeps both
        renewing = spec.holder_identity == s.identity
        transitions = (spec.lease_transitions or 0) + (0 if renewing else 1)
        lease.spec = client.V1LeaseSpec(
            holder_identity=s.identity,
            lease_duration_seconds=s.lease_seconds,
            acquire_time=spec.acquire_time if renewing and spec.acquire_time else now,
            renew_time=now,
            lease_transitions=transitions,
        )
        try:
            self._api.replace_namespaced_lease(s.name, s.namespace, lease)
        except ApiException as exc:
            if exc.status == 409:  # somebody else wrote first: they won this round
                return False
            with map_errors(f"update Lease {s.namespace}/{s.name}"):
                raise
        if not renewing:
            log.info("Took over Lease %s/%s from %s", s.namespace, s.name, spec.holder_identity)
        return True

    def _create(self) -> bool:
        s, now = self.settings, _now()
        body = client.V1Lease(
            metadata=client.V1ObjectMeta(name=s.name, namespace=s.namespace),
            spec=client.V1LeaseSpec(
                holder_identity=s.identity,
                lease_duration_seconds=s.lease_seconds,
                acquire_time=now,
                renew_time=now,
                lease_transitions=0,
            ),
        )
        try:
            self._api.create_namespaced_lease(s.namespace, body)
        except ApiException as exc:
            if exc.status == 409:
                return False
            with map_errors(f"create Lease {s.namespace}/{s.name}"):
                raise
        return True

    def _expired(self, spec: client.V1LeaseSpec) -> bool:
        renewed = spec.renew_time or spec.acquire_time
        if renewed is None:
            return True
        duration = spec.lease_duration_seconds or self.settings.lease_seconds
        return (_now() - renewed).total_seconds() > duration

    def release(self) -> None:
        """Give the Lease up (on a clean stop), so a standby takes over at once."""
        s = self.settings
        try:
            lease = self._api.read_namespaced_lease(s.name, s.namespace)
            if lease.spec and lease.spec.holder_identity == s.identity:
                lease.spec.holder_identity = None
                lease.spec.renew_time = None
                self._api.replace_namespaced_lease(s.name, s.namespace, lease)
        except ApiException:
            log.warning("Could not release Lease %s/%s", s.namespace, s.name)

    # -- loops --------------------------------------------------------------------------------

    def acquire(self, stop: threading.Event) -> bool:
        """Block until this identity holds the Lease (True) or `stop` is set (False)."""
        s = self.settings
        waiting_logged = False
        while not stop.is_set():
            try:
                if self.try_acquire():
                    log.info("Became leader (Lease %s/%s, %s)", s.namespace, s.name, s.identity)
                    return True
            except DependencyUnavailable as exc:
                log.warning("Leader election: %s", exc)
            if not waiting_logged:
                log.info("Waiting as standby for Lease %s/%s", s.namespace, s.name)
                waiting_logged = True
            stop.wait(s.retry_seconds)
        return False

    def hold(self, stop: threading.Event, on_lost: Callable[[], None]) -> threading.Thread:
        """Renew in a daemon thread until `stop`; call `on_lost` if renewing fails too long."""

        def renew() -> None:
            s = self.settings
            last_ok = time.monotonic()
            while not stop.wait(s.renew_seconds):
                try:
                    if self.try_acquire():
                        last_ok = time.monotonic()
                        continue
                    log.error("Lost Lease %s/%s to another replica", s.namespace, s.name)
                except DependencyUnavailable as exc:
                    if time.monotonic() - last_ok < s.lease_seconds - s.renew_seconds:
                        log.warning("Could not renew the Lease (will retry): %s", exc)
                        continue
                    log.error("Could not renew the Lease for %ss: %s", s.lease_seconds, exc)
                on_lost()
                return

        thread = threading.Thread(target=renew, name="fogfleet-lease", daemon=True)
        thread.start()
        return thread
