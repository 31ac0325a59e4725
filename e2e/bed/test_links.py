"""Link settings: parsing and validation (no namespaces needed; the e2e suite measures them)."""

from __future__ import annotations

import pytest

from e2e.bed import delayline, links
from e2e.bed.base import HarnessError


def test_a_computenode_network_entry_becomes_a_link() -> None:
    entry = {"type": "wifi", "latencyMillis": 4, "jitterMillis": 1.5, "bandwidthMbps": 100}
    assert links.LinkSpec.from_network(entry) == links.LinkSpec(4.0, 1.5, 100.0, 0.0)


def test_the_command_line_reads_units() -> None:
    ns = links.parse_args(["bed-robot-1", "--delay", "20ms", "--jitter", "0.5ms", "--loss", "100%"])
    assert ns.node == "bed-robot-1"
    assert links.change_from_args(ns) == {"delay_ms": 20.0, "jitter_ms": 0.5, "loss_percent": 100.0}
    ns = links.parse_args(["n", "--rate", "1gbit", "--delay", "0.1s"])
    assert links.change_from_args(ns) == {"rate_mbit": 1000.0, "delay_ms": 100.0}


def test_a_bad_unit_is_refused_with_the_expected_units() -> None:
    with pytest.raises(SystemExit):
        links.parse_args(["n", "--delay", "20 parsecs"])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [("delay_ms", -1.0, "must not be negative"), ("loss_percent", 101.0, "at most 100")],
)
def test_impossible_links_are_refused(field: str, value: float, message: str) -> None:
    with pytest.raises(HarnessError, match=message):
        links.LinkSpec(**{field: value})


def test_netlink_attributes_round_trip() -> None:
    packed = delayline._attr(2, b"\x01\x02\x03") + delayline._attr(1, b"\xaa" * 8)
    assert delayline._attrs(packed) == {2: b"\x01\x02\x03", 1: b"\xaa" * 8}
