"""The incremental data-UART parser (mmsnap_graph.io.ti.serial.stream): the
same packets whatever the reads' sizes, stamped with the read that completed
them, bounded state, counters of what it dropped."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io.ti.serial.packets import MAGIC_WORD, UartPacket
from mmsnap_graph.io.ti.serial.stream import BadFrame, UartStreamParser
from ti_encode import encode_oob_frame, encode_tracking_frame


def _packet(k, n=3, **kw):
    xyz = np.column_stack([np.full(n, 0.1 * k), np.linspace(1, 4, n), np.zeros(n)])
    return encode_oob_frame(k, xyz, np.full(n, 0.2), np.full(n, 15.0), np.full(n, 30.0), **kw)


def _damaged_stream():
    p = [_packet(k) for k in range(1, 13)]
    cut = p[3][:50]                                              # cut short by the next one
    wrong_len = bytearray(p[6])
    wrong_len[12:16] = (5_000_000).to_bytes(4, "little")         # implausible totalPacketLen
    return (b"noise" + b"".join(p[:3]) + cut + b"".join(p[4:6]) + bytes(wrong_len)
            + b"\x00" * 33 + b"".join(p[7:]) + p[0][:70])


def _summary(items):
    return [(type(i).__name__, i.index, i.byte_offset,
             i.frame_number, getattr(i, "reason", "")) for i in items]


def test_any_read_sizes_give_the_same_packets():
    data = _damaged_stream()
    whole = UartStreamParser()
    expected = _summary(whole.feed(data) + whole.finish())
    kinds = [k for k, *_ in expected]
    assert kinds.count("UartPacket") == 10
    rng = np.random.default_rng(3)
    for _ in range(20):
        parser, items, pos = UartStreamParser(), [], 0
        while pos < len(data):
            step = int(rng.integers(1, 700))
            items += parser.feed(data[pos:pos + step])
            pos += step
        assert _summary(items + parser.finish()) == expected
        assert parser.counts.good == 10 and parser.counts.bytes == len(data)


def test_what_the_damaged_stream_reports():
    parser = UartStreamParser()
    items = parser.feed(_damaged_stream()) + parser.finish()
    reasons = [str(i) for i in items if isinstance(i, BadFrame)]
    assert reasons[0] == "5 bytes before the first magic word"
    assert any("cut short: the next magic word comes at byte" in r for r in reasons)
    assert any("implausible totalPacketLen=5000000" in r for r in reasons)
    assert reasons[-1].endswith(f"truncated: 70 of {len(_packet(1))} bytes")
    # The bytes after the implausible header belong to it: no gap of their own.
    assert not any("without a magic word" in r for r in reasons)
    good = [i.frame_number for i in items if isinstance(i, UartPacket)]
    assert good == [1, 2, 3, 5, 6, 8, 9, 10, 11, 12]
    c = parser.counts
    assert (c.packets, c.good, c.bad) == (13, 10, 3)


def test_each_packet_is_stamped_by_the_read_that_completed_it():
    a, b = _packet(1), _packet(2)
    parser = UartStreamParser()
    assert parser.feed(a[:100], 10.0) == []
    (p1,) = parser.feed(a[100:] + b[:5], 10.5)
    (p2,) = parser.feed(b[5:], 11.25)
    assert (p1.host_time_s, p2.host_time_s) == (10.5, 11.25)
    assert (p1.byte_offset, p2.byte_offset) == (0, len(a))


def test_a_corrupted_length_does_not_stall_the_stream():
    """A length of 1 MB would make a naive reader wait for 11 s of data; the
    next magic word ends the packet as soon as it arrives."""
    bad = bytearray(_packet(1))
    bad[12:16] = (1_000_000).to_bytes(4, "little")
    parser = UartStreamParser()
    items = parser.feed(bytes(bad) + _packet(2))
    assert "cut short" in items[0].reason and items[1].frame_number == 2


def test_garbage_is_not_kept_and_is_reported_once_per_gap():
    parser = UartStreamParser()
    parser.feed(_packet(1))
    for _ in range(200):
        assert parser.feed(b"\x55" * 1000) == []
        assert len(parser._buf) < len(MAGIC_WORD)
    items = parser.feed(_packet(2))
    assert [str(i) for i in items[:1]] == [f"200000 bytes without a magic word at byte "
                                           f"{len(_packet(1))}, after packet 0 (frame 1)"]
    assert parser.counts.bytes_skipped == 200_000


def test_saturated_uart_and_sub_frames_are_counted():
    parser = UartStreamParser(frame_period_s=0.05, n_sub_frames=1)
    items = parser.feed(_packet(1, transmit_us=30_000) + _packet(2, transmit_us=46_000)
                        + _packet(3, sub_frame=1))
    assert parser.counts.saturated == 1
    assert "sub-frame 1: the configuration has 1 sub-frame(s)" in items[2].reason


def test_the_layout_of_the_stream_is_kept():
    rng = np.random.default_rng(1)
    parser = UartStreamParser()
    data = b"".join(encode_tracking_frame(k, rng.uniform(1, 5, 4), np.zeros(4), np.zeros(4),
                                          np.zeros(4)) for k in range(1, 4))
    items = parser.feed(data)
    assert parser.layout == "sdk" and {i.demo for i in items} == {"tracking"}


@pytest.mark.parametrize("kwargs", [dict(demo="x"), dict(n_sub_frames=0), dict(n_sub_frames=5),
                                    dict(frame_period_s=0.0), dict(frame_period_s=np.inf)])
def test_bad_options(kwargs):
    with pytest.raises(ValidationError):
        UartStreamParser(**kwargs)
