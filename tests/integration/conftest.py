"""The integration tier: ``make integration`` (``pytest tests -m integration``).

The rule: a test is in the integration tier when it carries the ``integration`` marker; every
other test under tests/ is a unit test, run by ``make unit`` (``pytest tests/unit -m "not
integration"``) and held under 1 s each (tests/conftest.py's guard fails one over 3 s of CPU
time when FOGFLEET_STRICT_UNIT=1). A test belongs here when it

* starts real processes or ROS 2 nodes (rclpy, ``python -m ...``, worker processes);
* runs the operator itself (KopfRunner against :mod:`fakeapi`);
* or takes more than a second (big hypothesis runs, GA runs on large fleets, plots).

Where it lives: a file whose every test is such a test lives under tests/integration/ (mirroring
the package) and needs no marker - tests/conftest.py marks this whole directory. A slow test that
shares its file's fixtures and helpers with fast tests stays in tests/unit/ beside them with
``@pytest.mark.integration``, so it is neither copied nor weakened. ``slow`` is still accepted as
an older name of the marker.

``pytest tests`` with no ``-m`` runs both tiers, as before.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from .fakeapi import FakeApi


@pytest.fixture
def api() -> Iterator[FakeApi]:
    """A fresh fake API server on 127.0.0.1 for one test."""
    with FakeApi() as fake:
        yield fake
