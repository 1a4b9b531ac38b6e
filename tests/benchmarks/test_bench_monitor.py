"""benchmarks/bench_monitor.py runs: its detection table on one case."""

import importlib.util
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_monitor",
                                                  ROOT / "benchmarks" / "bench_monitor.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_detection_prints_the_recalibrated_pose_error(capsys):
    # Configuration C, S2 turned by 2 deg at 60 s, seed 0: detected 2.7 s
    # later and re-calibrated (the table read Recalibration.success, which
    # the record does not have: the benchmark stopped at its first detection).
    distances = _bench().detection(1, networks=("C",), bumps=("2deg",))
    (mahal,) = distances["C", "2deg"]
    assert math.isfinite(mahal) and mahal < 16.27  # chi-square 3, p = 0.999
    table = capsys.readouterr().out
    assert "-> C 2deg: detected 1/1" in table
