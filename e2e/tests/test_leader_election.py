"""Leader election on a real Lease: one holder at a time, takeover after expiry, clean hand-off.

The API server's optimistic concurrency (resourceVersion) is what makes it safe; a fake would
accept both writers.
"""

from __future__ import annotations

import threading
import time

import pytest

from e2e.bed.kube import Kube
from e2e.tests.incluster import lease_time
from fogfleet.adapters.leases import LeaseLock, LeaseSettings

pytestmark = [pytest.mark.e2e, pytest.mark.portable, pytest.mark.timeout(120)]


def _lock(kube: Kube, namespace: str, identity: str) -> LeaseLock:
    settings = LeaseSettings(
        namespace=namespace,
        name="fogfleet-operator",
        identity=identity,
        lease_seconds=3,
        renew_seconds=1,
        retry_seconds=0.5,
    )
    return LeaseLock(kube.api_client(), settings)


def _holder(kube: Kube, namespace: str) -> str | None:
    lease = kube.kubectl_json("get", "lease", "fogfleet-operator", "-n", namespace)
    holder: str | None = lease["spec"].get("holderIdentity")
    return holder


def test_only_one_replica_holds_the_lease_and_a_standby_takes_over(
    kube: Kube, namespace: str
) -> None:
    a, b = _lock(kube, namespace, "replica-a"), _lock(kube, namespace, "replica-b")
    assert a.try_acquire() is True
    assert b.try_acquire() is False, "two holders of one Lease"
    assert _holder(kube, namespace) == "replica-a"

    stop_a, lost = threading.Event(), threading.Event()
    renewing = a.hold(stop_a, on_lost=lost.set)
    time.sleep(4)  # an observation window longer than the lease: renewals keep it
    assert b.try_acquire() is False
    assert not lost.is_set()

    stop_a.set()  # the leader dies without releasing
    renewing.join(10)  # its last renewal written
    renewed = lease_time(kube, "renewTime", namespace)
    stop_b = threading.Event()
    assert b.acquire(stop_b) is True
    # timed by the Lease's own stamps (both written by this process's clock), not by the
    # test: the standby takes over once the lease expired (3 s after the holder's last
    # renewal), within a retry (0.5 s) and its API round trips
    took = lease_time(kube, "acquireTime", namespace) - renewed
    assert 3 <= took <= 3 + 2, f"takeover {took:.1f}s after the last renewal (lease 3 s)"
    assert _holder(kube, namespace) == "replica-b"
    lease = kube.kubectl_json("get", "lease", "fogfleet-operator", "-n", namespace)
    assert lease["spec"]["leaseTransitions"] == 1


def test_a_released_lease_is_taken_at_once(kube: Kube, namespace: str) -> None:
    a, b = _lock(kube, namespace, "replica-a"), _lock(kube, namespace, "replica-b")
    assert a.try_acquire()
    time.sleep(1.1)  # so that an acquireTime kept from replica-a would show
    a.release()
    released = time.time()
    assert b.try_acquire() is True
    assert _holder(kube, namespace) == "replica-b"
    # the new holder acquired it now, not when replica-a did: a hand-off is a transition
    assert lease_time(kube, "acquireTime", namespace) >= released - 0.5
    lease = kube.kubectl_json("get", "lease", "fogfleet-operator", "-n", namespace)
    assert lease["spec"]["leaseTransitions"] == 1
