"""The header before the bytes the head and the tail exchange."""

from __future__ import annotations

import pytest

from fogfleet.contract.dnn import answer_topic, tensor_topic
from fogfleet.workload.dnn.wire import HEADER_BYTES, Kind, Packet, decode, encode


def test_a_packet_survives_encode_then_decode() -> None:
    p = Packet(Kind.ANSWER, 2, 2**40 + 7, 1_795_000_000_123_456_789, 1234, b"\x01\x02" * 100)
    data = encode(p)
    assert len(data) == HEADER_BYTES + 200 == 232
    assert decode(data) == p
    assert decode(bytearray(data)) == p and decode(memoryview(data)) == p


def test_a_probe_is_the_header_alone() -> None:
    p = Packet(Kind.PROBE, 0, 1, 5)
    assert len(encode(p)) == HEADER_BYTES and decode(encode(p)).payload == b""


def test_the_tails_compute_time_saturates_instead_of_overflowing() -> None:
    assert decode(encode(Packet(Kind.ANSWER, 0, 1, 0, tail_us=2**40))).tail_us == 2**32 - 1


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"FFDN", "shorter than the 32-byte header"),
        (b"XXXX" + bytes(28), "not a fogfleet split-DNN message"),
        (b"FFDN\x02" + bytes(27), "version 2"),
        (b"FFDN\x01\x09" + bytes(26), "kind 9"),
    ],
)
def test_a_foreign_or_broken_message_is_refused_with_the_reason(data: bytes, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        decode(data)


def test_fields_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match="action"):
        encode(Packet(Kind.TENSOR, 70000, 1, 0))


def test_topics_sit_under_the_module_as_a_ros_name() -> None:
    assert tensor_topic("object-detector") == "object_detector/dnn/tensor"
    assert answer_topic("detector") == "detector/dnn/answer"
