"""Test tiers (see tests/integration/conftest.py for the rule) and the unit tier's time guard.

Every test under tests/integration/, and every test marked ``slow`` (the tier's older name, still
accepted), gets the ``integration`` marker here, so ``-m integration`` / ``-m "not integration"``
select the tiers from any directory.

With ``FOGFLEET_STRICT_UNIT=1`` (``make unit`` sets it) a test outside the integration tier fails
when its setup and call take more than :data:`UNIT_LIMIT_SECONDS`. A unit test is meant to take
under 1 s; the guard allows three times that, so a machine busy with other jobs does not make it
flaky, while the tests that belong in the integration tier (1 s to 20 s each, measured) still
show up.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

INTEGRATION = Path(__file__).parent / "integration"
STRICT_ENV = "FOGFLEET_STRICT_UNIT"
UNIT_LIMIT_SECONDS = 3.0
_SPENT = pytest.StashKey[float]()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if INTEGRATION in item.path.parents or item.get_closest_marker("slow") is not None:
            item.add_marker(pytest.mark.integration)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    report: pytest.TestReport = yield
    if os.environ.get(STRICT_ENV) != "1" or item.get_closest_marker("integration") is not None:
        return report
    if call.when == "setup":
        item.stash[_SPENT] = call.duration
    elif call.when == "call" and report.passed:
        spent = item.stash.get(_SPENT, 0.0) + call.duration
        if spent > UNIT_LIMIT_SECONDS:
            report.outcome = "failed"
            report.longrepr = (
                f"{item.nodeid} took {spent:.1f} s (setup + call), over the unit tier's "
                f"{UNIT_LIMIT_SECONDS:.0f} s limit ({STRICT_ENV}=1): make it faster, or mark it "
                "@pytest.mark.integration (tests/integration/conftest.py says where it goes)"
            )
    return report
