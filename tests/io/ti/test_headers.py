"""Units written in point-table headers and the header sets of TI's tools
(mmsnap_graph.io.ti.headers)."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.ti.headers import (PRESETS, detect_preset, header_unit, suggest_preset,
                                        unit_factor)


@pytest.mark.parametrize("header, expected", [
    ("X (m)", ("x", "m")), ("Doppler (m/s)", ("doppler", "m/s")),
    ("Azimuth [deg]", ("azimuth", "deg")), ("  Timestamp (ms) ", ("timestamp", "ms")),
    ("SNR (0.1 dB)", ("snr", "0.1db")), ("frame", ("frame", None)), ("(m)", ("(m)", None)),
    ("Track index", ("track index", None)),
])
def test_header_unit(header, expected):
    assert header_unit(header) == expected


def test_unit_factors_and_a_unit_of_another_quantity():
    assert unit_factor("azimuth_rad", "deg", "Azimuth (deg)", "t.csv") == pytest.approx(np.pi / 180)
    assert unit_factor("time_s", "ms", "Timestamp (ms)", "t.csv") == 1e-3
    assert unit_factor("x_m", "cm", "X (cm)", "t.csv") == 0.01
    assert unit_factor("snr_db", "linear", "SNR (linear)", "t.csv") is None
    with pytest.raises(FileFormatError, match=r"t.csv: column 'X \(ft\)' is in 'ft', which is "
                                              r"not a unit of x_m \(units read: \['cm', 'm'"):
        unit_factor("x_m", "ft", "X (ft)", "t.csv")
    with pytest.raises(FileFormatError, match="not a unit of doppler_mps"):
        unit_factor("doppler_mps", "deg", "Doppler (deg)", "t.csv")


def test_the_sdk_scripts_header_is_recognised_and_others_suggested():
    assert detect_preset(["frame", "DetObj#", "x", "y", "z", "v", "snr", "noise"]) == "sdk-script"
    assert detect_preset(["frame", "x", "y", "z", "v", "snr"]) is None          # no signature
    assert detect_preset(["frame", "DetObj#", "x", "y", "z", "v", "rcs"]) is None  # a stranger
    assert suggest_preset(["frameNum", "timestamp", "X", "Y", "Z", "Velocity"]) == "visualizer"
    assert suggest_preset(["a", "b", "X"]) is None
    assert PRESETS["sdk-script"].columns["snr"] == ("snr_db", "0.1db")
