"""Test tiers (see tests/integration/conftest.py for the rule) and the unit tier's cost guard.

Every test under tests/integration/, and every test marked ``slow`` (the tier's older name, still
accepted), gets the ``integration`` marker here, so ``-m integration`` / ``-m "not integration"``
select the tiers from any directory.

With ``FOGFLEET_STRICT_UNIT=1`` (``make unit`` sets it) a test outside the integration tier fails
when its setup and call cost more than :data:`UNIT_LIMIT_CPU_SECONDS` of CPU time: the test
process's own user and system time plus that of the child processes it waited for
(``os.times``). CPU time, not wall time: wall time measures the machine's load as much as the
test (a test that waits on a busy 2-core machine is not a slow test), while the CPU a test burns
is its own and nearly the same on a quiet or a loaded machine. A unit test is meant to cost
under 1 s; the guard allows three times that, while the tests that belong in the integration
tier (1 s to 20 s each, measured) still show up. A test that sleeps or waits for long costs no
CPU and passes the guard; the tier's other rule (no processes, no network) keeps those out.

Hypothesis runs under the ``fogfleet`` profile: no per-example deadline and no ``too_slow``
health check, both wall-clock verdicts that a loaded machine reaches. A test's own
``@settings`` that names ``suppress_health_check`` replaces the profile's list, so such a
test names ``too_slow`` itself.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("fogfleet", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("fogfleet")

INTEGRATION = Path(__file__).parent / "integration"
STRICT_ENV = "FOGFLEET_STRICT_UNIT"
UNIT_LIMIT_CPU_SECONDS = 3.0
_SPENT = pytest.StashKey[float]()


def cpu_seconds() -> float:
    """This process's CPU time so far, and its waited-for children's (user + system)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _strict(item: pytest.Item) -> bool:
    return os.environ.get(STRICT_ENV) == "1" and item.get_closest_marker("integration") is None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if INTEGRATION in item.path.parents or item.get_closest_marker("slow") is not None:
            item.add_marker(pytest.mark.integration)


@contextmanager
def _charged_to(item: pytest.Item) -> Iterator[None]:
    """Add the CPU the block costs to ``item``'s account."""
    start = cpu_seconds()
    try:
        yield
    finally:
        item.stash[_SPENT] = item.stash.get(_SPENT, 0.0) + cpu_seconds() - start


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    item.stash[_SPENT] = 0.0
    with _charged_to(item):
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    with _charged_to(item):
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    report: pytest.TestReport = yield
    if call.when != "call" or not report.passed or not _strict(item):
        return report
    spent = item.stash.get(_SPENT, 0.0)
    if spent > UNIT_LIMIT_CPU_SECONDS:
        report.outcome = "failed"
        report.longrepr = (
            f"{item.nodeid} cost {spent:.1f} s of CPU (setup + call), over the unit tier's "
            f"{UNIT_LIMIT_CPU_SECONDS:.0f} s limit ({STRICT_ENV}=1): make it cheaper, or mark it "
            "@pytest.mark.integration (tests/integration/conftest.py says where it goes)"
        )
    return report
