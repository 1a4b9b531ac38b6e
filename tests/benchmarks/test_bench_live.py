"""benchmarks/bench_live.py: a slot's latency is taken from the packet its
boards sent for it, also after live's clock re-anchored."""

import importlib.util
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_live", ROOT / "benchmarks" / "bench_live.py")
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(ROOT / "tests"))
    spec.loader.exec_module(module)
    return module


def test_latency_after_a_reanchor_is_of_the_slots_own_packet():
    bench = _bench()
    # Board S1 started at scene packet 2 (frame numbers from 1: its first
    # frame is number 3, slot 3); its clock re-anchored at slot 10 (a slot
    # skipped: the board's frame 10 went to slot 11). Each line is read 3 ms
    # after its slot's packet was written.
    first_packet, period = 2, 0.05
    numbers = np.arange(3, 21)
    slots = np.where(numbers < 10, numbers, numbers + 1)
    write = {int(k): 100.0 + (k - 1) * period for k in numbers}          # packet k - 1
    board = SimpleNamespace(first_packet=first_packet,
                            write_times=[write[int(k)] for k in numbers])
    md = {"S1_board_frame_offset": 0, "S1_board_frame_offsets": [[3, 0], [11, 1]]}
    lines = [(write[int(k)] + 0.003, json.dumps({"frame": int(s)}))
             for k, s in zip(numbers, slots)]
    lat, when = bench.latency({"S1": board}, lines, SimpleNamespace(metadata=md))
    np.testing.assert_allclose(lat, 3.0, atol=1e-6)
    assert when.size == numbers.size
    assert bench.packet_of_slot(md, "S1", 2) is None
