"""The arguments of the TI ``.cfg`` waveform commands (mmsnap_graph.io.ti.cfg_fields),
against the mmWave SDK user guide's command list and the radar's hardware
limits; and the limits as the ``.cfg`` parser applies them, at their edges."""

from __future__ import annotations

import pytest

from mmsnap_graph.errors import ConfigurationError
from mmsnap_graph.io.ti.cfg import parse_ti_cfg
from mmsnap_graph.io.ti.cfg_fields import cfg_fields, cfg_fields_table

from _shared import ROOT, TI_DATA

#: The SDK user guide's argument lists, in order (the names the errors use).
SDK_ARGUMENTS = {
    "profileCfg": ["profileId", "startFreq", "idleTime", "adcStartTime", "rampEndTime",
                   "txOutPower", "txPhaseShifter", "freqSlopeConst", "txStartTime",
                   "numAdcSamples", "digOutSampleRate", "hpfCornerFreq1", "hpfCornerFreq2",
                   "rxGain"],
    "chirpCfg": ["startIdx", "endIdx", "profileId", "startFreqVar", "freqSlopeVar",
                 "idleTimeVar", "adcStartTimeVar", "txEnableMask"],
    "frameCfg": ["chirpStartIdx", "chirpEndIdx", "numLoops", "numFrames", "framePeriodicity",
                 "triggerSelect", "frameTriggerDelay"],
    "channelCfg": ["rxChannelEn", "txChannelEn", "cascading"],
    "adcCfg": ["numADCBits", "adcOutputFmt"],
    "dfeDataOutputMode": ["modeType"],
}


@pytest.mark.parametrize("command", sorted(SDK_ARGUMENTS))
def test_argument_names_and_order_are_the_sdks(command):
    fields = cfg_fields(command, len(SDK_ARGUMENTS[command]))
    assert [f[0] for f in fields] == SDK_ARGUMENTS[command]


def test_every_range_is_ordered_and_integer_fields_have_integer_bounds():
    commands = [(c, len(a)) for c, a in SDK_ARGUMENTS.items()] + [
        ("advFrameCfg", 5), ("subFrameCfg", 10), ("adcbufCfg", 5), ("adcbufCfg", 4),
        ("sensorPosition", 2), ("sensorPosition", 3), ("sensorPosition", 5)]
    for command, n in commands:
        fields = cfg_fields(command, n)
        assert len(fields) == n, command
        for name, integer, low, high in fields:
            assert (low is None) == (high is None), (command, name)
            if low is not None:
                assert low <= high, (command, name)
                if integer:
                    assert float(low).is_integer() and float(high).is_integer(), (command, name)


def test_variable_length_commands_take_their_last_or_their_own_arguments():
    # adcbufCfg: SDK 2.x has no sub-frame index in front of the four others.
    assert [f[0] for f in cfg_fields("adcbufCfg", 4)] == [f[0] for f in cfg_fields(
        "adcbufCfg", 5)][1:]
    assert cfg_fields("adcbufCfg", 5)[0][:2] == ("subFrameIdx", True)
    # sensorPosition: height and tilt(s); five values add the x, y offsets in front.
    assert [f[0] for f in cfg_fields("sensorPosition", 2)] == ["height", "elevationTilt"]
    assert [f[0] for f in cfg_fields("sensorPosition", 5)][:2] == ["xOffset", "yOffset"]


def test_hardware_limits():
    by_name = {f[0]: f for f in cfg_fields("frameCfg", 7)}
    # The frame timer counts 5 ns ticks in 28 bits: 5e-9 s x 2^28 = 1342.18 ms.
    assert by_name["framePeriodicity"][3] == pytest.approx(5e-9 * 2**28 * 1e3, abs=0.005)
    assert by_name["numLoops"][2:] == (1, 255)
    chirp = {f[0]: f for f in cfg_fields("chirpCfg", 8)}
    assert chirp["endIdx"][2:] == (0, 511)            # a chirp table of 512 entries
    assert cfg_fields("advFrameCfg", 5)[0][2:] == (1, 4)  # at most four sub-frames


def _fast_cfg(num_loops: str) -> str:
    lines = (TI_DATA / "dca1000_fast.cfg").read_text().splitlines()
    for i, line in enumerate(lines):
        words = line.split()
        if words[:1] == ["frameCfg"]:
            words[3] = num_loops
            lines[i] = " ".join(words)
    return "\n".join(lines) + "\n"


def test_the_parser_accepts_a_limit_and_names_the_field_just_past_it():
    ti = parse_ti_cfg(_fast_cfg("255"), board="AWR1843BOOST")
    assert ti.configs[0].n_loops == 255
    with pytest.raises(ConfigurationError, match=r"numLoops=256 must lie in \[1, 255\]"):
        parse_ti_cfg(_fast_cfg("256"), board="AWR1843BOOST")
    with pytest.raises(ConfigurationError, match=r"numLoops=2.5 must be an integer"):
        parse_ti_cfg(_fast_cfg("2.5"), board="AWR1843BOOST")


def test_the_docs_quote_the_bounds_the_reader_checks():
    """docs/TI.md lists each bounded .cfg argument with its range and unit,
    as the reader's own table (before: only a few examples in prose)."""
    table = cfg_fields_table()
    assert table in (ROOT / "docs" / "TI.md").read_text()
    assert "| `frameCfg` | `chirpStartIdx` 0..511; `chirpEndIdx` 0..511; `numLoops` 1..255 loops;" \
        in table
    for command, n_args in [(c, len(a)) for c, a in SDK_ARGUMENTS.items()] + [
            ("subFrameCfg", 10), ("advFrameCfg", 5), ("adcbufCfg", 5), ("sensorPosition", 5)]:
        for name, integer, low, high in cfg_fields(command, n_args):
            if low is not None:
                span = f"{low:g}..{high:g}" if integer else f"[{low:g}, {high:g}]"
                assert f"`{name}` {span}" in table, (command, name)
