"""TI mmWave SDK .cfg parsing into RadarConfig (mmsnap_graph.io.ti.cfg)."""


import copy
import json
import time

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mmsnap_graph.data.radar_config import SPEED_OF_LIGHT_MPS, TABLE_I, RadarConfig
from mmsnap_graph.errors import ConfigurationError, FileFormatError, MmsnapError
from mmsnap_graph.app.cli import main
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.ti.cfg import (
    BOARD_PRESETS,
    BoardLayout,
    parse_ti_cfg,
    read_ti_cfg,
    read_boundary_boxes,
)
from ti_samples import DCA_CFG, FAST_CFG, studio_json

from _shared import TI_DATA as DATA

LEGACY = """\
% comment line
sensorStop
dfeDataOutputMode 1
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 20 3 44 0 0 56.25 1 512 12500 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
chirpCfg 2 2 0 0 0 0 0 2
frameCfg 0 2 32 0 100 1 0
guiMonitor -1 1 1 0 0 0 1
sensorStart
"""


def test_issue_usrr_sub_frame_in_ti_terms():
    ti = read_ti_cfg(DATA / "awr1843_advanced.cfg", board="AWR1843BOOST")
    assert ti.advanced and ti.n_sub_frames == 3
    usrr = ti.configs[2]
    assert (usrr.n_loops, usrr.n_tx, usrr.n_rx, usrr.n_samples) == (32, 3, 4, 512)
    assert usrr.sample_rate_hz == pytest.approx(12.5e6)
    assert usrr.slope_hz_per_s == pytest.approx(56.25e12)
    assert usrr.chirp_period_s == pytest.approx(64e-6)          # idle 20 + ramp end 44
    assert usrr.adc_start_s == pytest.approx(3e-6)
    assert usrr.tx_channels == (0, 2, 1)
    # Firing order TX0, TX2, TX1 on the AWR1843 layout: TX2 at 4, TX1 raised at 2.
    assert usrr.tx_azimuth_half_wl == (0.0, 4.0, 2.0)
    assert usrr.tx_elevation_half_wl == (0.0, 0.0, 1.0)
    # Band centre: 77 GHz + 56.25 MHz/us * (3 us + 512 / 12.5 MHz / 2) = 78.32 GHz.
    centre = 77e9 + 56.25e12 * (3e-6 + 512 / 12.5e6 / 2)
    assert usrr.band_centre_hz == pytest.approx(centre)
    assert usrr.wavelength_m == pytest.approx(SPEED_OF_LIGHT_MPS / centre)
    # The frame period is the sum of the sub-frame periods (10 + 10 + 30 ms).
    assert all(c.frame_period_s == pytest.approx(0.05) for c in ti.configs)
    assert ti.configs[0].tx_channels == (0, 2) and ti.configs[0].n_loops == 64


def test_legacy_frame_and_defaults_unchanged():
    ti = parse_ti_cfg(LEGACY, board="IWR6843ISK")
    (cfg,) = ti.configs
    assert not ti.advanced and cfg.frame_period_s == pytest.approx(0.1)
    assert cfg.complex_adc and cfg.wavelength_reference == "band_centre"
    assert RadarConfig.from_dict(cfg.to_dict()) == cfg
    # The paper's configuration is untouched by the new optional fields.
    assert TABLE_I.wavelength_m == SPEED_OF_LIGHT_MPS / 76e9
    assert "adc_start_s" not in TABLE_I.to_dict()


def test_oob_sample_is_the_sparse_20_fps_demo():
    (cfg,) = read_ti_cfg(DATA / "iwr1843_oob.cfg", board="IWR1843BOOST").configs
    assert cfg.frame_period_s == pytest.approx(0.05)
    assert cfg.max_doppler_mps == pytest.approx(0.973, abs=2e-3)


def test_real_adc_halves_max_range():
    text = LEGACY.replace("adcCfg 2 1", "adcCfg 2 0").replace("adcbufCfg -1 0 1 1 1",
                                                              "adcbufCfg -1 1 1 1 1")
    (cfg,) = parse_ti_cfg(text, board="AWR1843BOOST").configs
    assert not cfg.complex_adc
    (ref,) = parse_ti_cfg(LEGACY, board="AWR1843BOOST").configs
    assert cfg.max_range_m == pytest.approx(ref.max_range_m / 2)


def test_aop_layout_has_a_four_element_azimuth_row():
    (cfg,) = parse_ti_cfg(LEGACY.replace("chirpCfg 1 1 0 0 0 0 0 4", "chirpCfg 1 1 0 0 0 0 0 2")
                          .replace("chirpCfg 2 2 0 0 0 0 0 2", "chirpCfg 2 2 0 0 0 0 0 4"),
                          board="IWR6843AOP").configs
    assert cfg.n_azimuth == 4
    assert np.all(cfg.virtual_elevation_half_wl[list(cfg.azimuth_channels)] == 0)


@pytest.mark.parametrize("board", sorted(BOARD_PRESETS))
def test_every_preset_builds_a_uniform_azimuth_array(board):
    (cfg,) = parse_ti_cfg(LEGACY, board=board).configs
    assert cfg.n_azimuth >= 4


def test_explicit_layout_and_missing_board():
    lay = BoardLayout(name="mine", tx_azimuth_half_wl=(0, 0, 4), tx_elevation_half_wl=(0, 1, 0),
                      rx_azimuth_half_wl=(0, 1, 2, 3))
    (cfg,) = parse_ti_cfg(LEGACY, layout=lay).configs
    assert cfg.tx_azimuth_half_wl == (0.0, 4.0, 0.0)
    with pytest.raises(ConfigurationError, match="does not say where the antennas are"):
        parse_ti_cfg(LEGACY)
    with pytest.raises(ConfigurationError, match="unknown board 'XYZ'"):
        parse_ti_cfg(LEGACY, board="XYZ")


@pytest.mark.parametrize("old, new, match", [
    ("guiMonitor -1 1 1 0 0 0 1", "fooCfg 1 2", r"line 12: unknown command 'fooCfg'"),
    ("frameCfg 0 2 32 0 100 1 0", "frameCfg 0 2 32 0 100 1", r"line 11: frameCfg takes 7"),
    ("chirpCfg 2 2 0 0 0 0 0 2", "chirpCfg 2 2 0 0 0 0 0 6", r"line 10: .*exactly one"),
    ("chirpCfg 2 2 0 0 0 0 0 2", "chirpCfg 1 2 0 0 0 0 0 2", r"line 10: chirp 1 is already"),
    ("chirpCfg 2 2 0 0 0 0 0 2", "chirpCfg 2 2 5 0 0 0 0 2", r"line 10: .*profile 5"),
    ("chirpCfg 2 2 0 0 0 0 0 2", "chirpCfg 2 2 0 0 0 0 0 1", r"line 11: .*transmitter twice"),
    ("channelCfg 15 7 0", "channelCfg 15 5 0", r"line 11: frameCfg fires TX\[1\]"),
    ("dfeDataOutputMode 1", "dfeDataOutputMode 3", r"line 3: dfeDataOutputMode 3 contradicts"),
    ("adcbufCfg -1 0 1 1 1", "adcbufCfg -1 1 1 1 1", r"line 6: adcbufCfg says real"),
    ("profileCfg 0 77 20 3 44", "profileCfg 0 77 20 3 40", r"line 7: .*ends after ramp_end"),
    ("frameCfg 0 2 32 0 100 1 0", "frameCfg 0 2 32 0 1 1 0", r"line 7: .*frame_period_s"),
    ("frameCfg 0 2 32 0 100 1 0", "frameCfg 0 3 32 0 100 1 0", r"line 11: .*chirp 3"),
    ("adcCfg 2 1", "adcCfg 2 x", r"line 5: adcCfg arguments must be numbers"),
    ("sensorStart", "frameCfg 0 2 32 0 100 1 0", r"line 13: frameCfg is given again"),
])
def test_bad_cfg_names_the_line(old, new, match):
    assert old in LEGACY
    with pytest.raises(ConfigurationError, match=match):
        parse_ti_cfg(LEGACY.replace(old, new, 1), board="AWR1843BOOST")


def test_advanced_frame_errors():
    text = (DATA / "awr1843_advanced.cfg").read_text()
    with pytest.raises(ConfigurationError, match=r"subFrameCfg missing for \[2\]"):
        parse_ti_cfg(text.replace("subFrameCfg 2 0 2 3 32 30 0 1 1 30", ""), board="AWR1843BOOST")
    with pytest.raises(ConfigurationError, match=r"line 23: .*numOfBurst=2"):
        parse_ti_cfg(text.replace("subFrameCfg 2 0 2 3 32 30 0 1 1 30",
                                  "subFrameCfg 2 0 2 3 32 30 0 2 1 30"), board="AWR1843BOOST")
    with pytest.raises(ConfigurationError, match="contradict each other"):
        parse_ti_cfg(text + "frameCfg 0 1 16 0 100 1 0\n", board="AWR1843BOOST")


def test_missing_file_and_extra_commands(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        read_ti_cfg(tmp_path / "none.cfg", board="AWR1843BOOST")
    text = LEGACY.replace("guiMonitor -1 1 1 0 0 0 1", "myVendorCmd 1 2 3")
    assert parse_ti_cfg(text, board="AWR1843BOOST", extra_commands=["myVendorCmd"]).configs


def test_sensor_position_is_kept():
    ti = parse_ti_cfg(LEGACY + "sensorPosition 2 0 15\n", board="IWR6843ISK")
    assert ti.sensor_height_m == 2.0
    assert ti.elevation_tilt_rad == pytest.approx(np.deg2rad(15))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.sampled_from(LEGACY.splitlines() + ["profileCfg 1 2", "chirpCfg a",
                                                         "frameCfg 0 9 1 0 1 1 0", "% x",
                                                         "advFrameCfg 1 0 0 1 0", ""]),
                max_size=14))
def test_parser_raises_only_project_errors(lines):
    try:
        parse_ti_cfg("\n".join(lines), board="AWR1843BOOST")
    except MmsnapError:
        pass


def _studio(advanced):
    profile = {"profileId": 0, "startFreqConst_GHz": 77.0, "idleTimeConst_usec": 20.0,
               "adcStartTimeConst_usec": 3.0, "rampEndTime_usec": 44.0,
               "freqSlopeConst_MHz_usec": 56.25, "txStartTime_usec": 1.0,
               "numAdcSamples": 512, "digOutSampleRate": 12500, "rxGain_dB": "0x1E"}
    chirps = [{"rlChirpCfg_t": {"chirpStartIdx": k, "chirpEndIdx": k, "profileId": 0,
                                "startFreqVar_MHz": 0.0, "freqSlopeVar_KHz_usec": 0.0,
                                "idleTimeVar_usec": 0.0, "adcStartTimeVar_usec": 0.0,
                                "txEnable": tx}} for k, tx in enumerate(["0x1", "0x4", "0x2"])]
    rf = {"rlChanCfg_t": {"rxChannelEn": "0xF", "txChannelEn": "0x7"},
          "rlAdcOutCfg_t": {"fmt": {"b2AdcBits": 2, "b2AdcOutFmt": 1}},
          "rlProfiles": [{"rlProfileCfg_t": profile}], "rlChirps": chirps}
    if advanced:
        sub = {"forceProfileIdx": 0, "chirpStartIdx": 0, "numOfChirps": 3, "numLoops": 32,
               "burstPeriodicity_msec": 10.0, "chirpStartIdxOffset": 0, "numOfBurst": 1,
               "numOfBurstLoops": 1, "subFramePeriodicity_msec": 10.0}
        rf["waveformType"] = "advancedFrameChirp"
        rf["rlAdvFrameCfg_t"] = {"frameSeq": {"numOfSubFrames": 2, "numFrames": 0,
                                              "subFrameCfg": [sub, dict(sub, numLoops=16)]}}
    else:
        rf["rlFrameCfg_t"] = {"chirpStartIdx": 0, "chirpEndIdx": 2, "numLoops": 32,
                              "numFrames": 0, "framePeriodicity_msec": 100.0}
    return {"mmWaveDevices": [{"mmWaveDeviceId": 0, "rfConfig": rf}]}


def test_mmwave_studio_json_matches_the_cfg(tmp_path):
    path = tmp_path / "capture.mmwave.json"
    path.write_text(json.dumps(_studio(False)))
    (cfg,) = read_ti_cfg(path, board="AWR1843BOOST").configs
    (ref,) = parse_ti_cfg(LEGACY, board="AWR1843BOOST").configs
    assert cfg == ref
    path.write_text(json.dumps(_studio(True)))
    ti = read_ti_cfg(path, board="AWR1843BOOST")
    assert ti.advanced and [c.n_loops for c in ti.configs] == [32, 16]
    assert ti.configs[0].frame_period_s == pytest.approx(0.02)


def test_mmwave_studio_json_errors_name_the_field(tmp_path):
    bad = _studio(False)
    bad["mmWaveDevices"][0]["rfConfig"]["rlChirps"][1]["rlChirpCfg_t"]["txEnable"] = "0x3"
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(ConfigurationError, match=r"bad.json rfConfig.rlChirps\[1\]: .*exactly one"):
        read_ti_cfg(path, board="AWR1843BOOST")
    del bad["mmWaveDevices"][0]["rfConfig"]["rlFrameCfg_t"]
    path.write_text(json.dumps(bad))
    with pytest.raises(FileFormatError, match="missing or malformed field 'rlFrameCfg_t'"):
        read_ti_cfg(path, board="AWR1843BOOST")
    path.write_text("{not json")
    with pytest.raises(FileFormatError, match="not a JSON file"):
        read_ti_cfg(path, board="AWR1843BOOST")


@pytest.mark.parametrize("kw, match", [
    (dict(adc_start_s=-1e-6), "adc_start_s"),
    (dict(complex_adc="yes"), "complex_adc"),
    (dict(rx_elevation_half_wl=(0, 1)), "rx_elevation_half_wl has 2"),
    (dict(tx_channels=(0, 1)), "tx_channels"),
    (dict(wavelength_reference="middle"), "wavelength_reference"),
    (dict(adc_start_s=20e-6), r"after adc_start_s=2e-05 takes longer"),
])
def test_radar_config_ti_fields_are_validated(kw, match):
    with pytest.raises(ConfigurationError, match=match):
        RadarConfig(**kw)


def test_band_centre_wavelength_and_round_trip():
    cfg = RadarConfig(adc_start_s=5e-6, wavelength_reference="band_centre", tx_channels=(0, 1, 2))
    centre = 76e9 + 83e12 * (5e-6 + 512 / 10e6 / 2)
    assert cfg.band_centre_hz == pytest.approx(centre)
    assert cfg.wavelength_m == pytest.approx(SPEED_OF_LIGHT_MPS / centre)
    assert cfg.max_doppler_mps < TABLE_I.max_doppler_mps
    assert RadarConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigurationError, match="unknown radar configuration fields"):
        RadarConfig.from_dict({"adc_start": 1.0})


# ---- every number, shape and nesting: a project error naming the field ----------------
def _edit(text, command, index, value):
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.split()[:1] == [command]:
            words = line.split()
            words[index] = value
            lines[i] = " ".join(words)
            return "\n".join(lines) + "\n"
    raise AssertionError(command)


@pytest.mark.parametrize("command, index, value, match", [
    ("profileCfg", 11, "0", r"digOutSampleRate=0 must lie in \[1, 100000\]"),
    ("profileCfg", 10, "nan", r"numAdcSamples=nan must be a finite number"),
    ("profileCfg", 1, "inf", r"profileId=inf must be a finite number"),
    ("profileCfg", 2, "1e400", r"startFreq=1e400 must be a finite number"),
    ("profileCfg", 10, "64.5", r"numAdcSamples=64.5 must be an integer"),
    ("chirpCfg", 2, "10000000", r"endIdx=10000000 must lie in \[0, 511\]"),
    ("chirpCfg", 8, "1e30", r"txEnableMask=1e30 must lie in \[0, 255\]"),
    ("advFrameCfg", 1, "10000000", r"numOfSubFrames=10000000 must lie in \[1, 4\]"),
    ("subFrameCfg", 5, "100000", r"numLoops=100000 must lie in \[1, 255\]"),
    ("subFrameCfg", 10, "0", r"subFramePeriodicity=0 must lie in \[0.001, 1342.18\]"),
    ("channelCfg", 1, "0", r"rxChannelEn=0 must lie in \[1, 255\]"),
    ("adcbufCfg", 1, "9", r"subFrameIdx=9 must lie in \[-1, 3\]"),
])
def test_bad_numbers_name_the_field(command, index, value, match):
    start = time.perf_counter()
    with pytest.raises(ConfigurationError, match=match):
        parse_ti_cfg(_edit(DCA_CFG, command, index, value), board="AWR1843BOOST")
    assert time.perf_counter() - start < 0.5


@pytest.mark.parametrize("index, value, match", [
    (5, "0", r"framePeriodicity=0 must lie in \[0.001, 1342.18\]"),
    (5, "1e9", r"framePeriodicity=1e9 must lie in \[0.001, 1342.18\]"),
    (2, "10000000", r"chirpEndIdx=10000000 must lie in \[0, 511\]"),
    (3, "-3", r"numLoops=-3 must lie in \[1, 255\]"),
])
def test_bad_frame_numbers(index, value, match):
    with pytest.raises(ConfigurationError, match=match):
        parse_ti_cfg(_edit(FAST_CFG, "frameCfg", index, value), board="AWR1843BOOST")


def test_seeded_mutations_raise_only_project_errors():
    """Every argument of both sample .cfgs set to an odd value: only the
    project's errors, each in well under a second (measured: 0.9 ms on average
    on the machine that wrote this; before, ``chirpCfg`` end 10^7 took seconds
    and a gigabyte)."""
    values = ["0", "-1", "nan", "inf", "-inf", "1e400", "10000000", "9223372036854775808",
              "0.5", "-1e300", "1e-300", "65536"]
    rng = np.random.default_rng(0)
    cases = 0
    for text in (DCA_CFG, FAST_CFG):
        lines = text.splitlines()
        for i, line in enumerate(lines):
            words = line.split()
            if not words or words[0].startswith("%") or len(words) == 1:
                continue
            for j in range(1, len(words)):
                for value in rng.choice(values, 4, replace=False):
                    edited = words[:j] + [str(value)] + words[j + 1:]
                    start = time.perf_counter()
                    try:
                        parse_ti_cfg("\n".join(lines[:i] + [" ".join(edited)] + lines[i + 1:]),
                                     board="AWR1843BOOST")
                    except MmsnapError:
                        pass
                    assert time.perf_counter() - start < 0.5, (line, j, value)
                    cases += 1
    assert cases > 400


def test_studio_sample_reads_like_its_cfg(tmp_path, capsys):
    a = read_ti_cfg(DATA / "dca1000_fast.mmwave.json", board="AWR1843BOOST")
    b = read_ti_cfg(DATA / "dca1000_fast.cfg", board="AWR1843BOOST")
    assert a.configs == b.configs
    assert json.loads((DATA / "dca1000_fast.mmwave.json").read_text()) == studio_json()
    assert main(["import", "dca1000", "--cfg", str(DATA / "dca1000_fast.mmwave.json"),
                 "--board", "AWR1843BOOST", "--node", f"S1={DATA / 'dca1000_fast.bin'}",
                 "-o", str(tmp_path / "fast.h5")]) == 0
    assert read_recording(tmp_path / "fast.h5").nodes["S1"].cube.shape[0] == 3


def _studio_file(tmp_path, change):
    doc = copy.deepcopy(studio_json())
    change(doc["mmWaveDevices"][0]["rfConfig"])
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(doc))
    return path


def _set(path, value):
    def change(rf):
        obj = rf
        for key in path[:-1]:
            obj = obj[key]
        obj[path[-1]] = value
    return change


@pytest.mark.parametrize("change, error, match", [
    (_set(("rlProfiles", 0, "rlProfileCfg_t", "digOutSampleRate"), 0), ConfigurationError,
     r"rfConfig.rlProfiles\[0\]: profileCfg digOutSampleRate=0.0 must lie in"),
    (_set(("rlProfiles", 0, "rlProfileCfg_t", "numAdcSamples"), float("nan")),
     ConfigurationError, r"numAdcSamples=nan must be a finite number"),
    (_set(("rlChirps", 1, "rlChirpCfg_t", "chirpStartIdx"), float("inf")), ConfigurationError,
     r"rfConfig.rlChirps\[1\]: chirpCfg startIdx=inf must be a finite number"),
    (_set(("rlFrameCfg_t", "numLoops"), 10 ** 400), ConfigurationError,
     r"numLoops=inf must be a finite number"),  # beyond the float range: read as inf
    (_set(("rlFrameCfg_t", "chirpEndIdx"), 10 ** 7), ConfigurationError,
     r"rfConfig.rlFrameCfg_t: frameCfg chirpEndIdx=10000000.0 must lie in \[0, 511\]"),
    (_set(("rlProfiles",), {"rlProfileCfg_t": {}}), FileFormatError,
     r"rfConfig.rlProfiles must be an array, got dict"),
    (_set(("rlChanCfg_t",), [15, 7]), FileFormatError,
     r"rfConfig.rlChanCfg_t must be an object, got list"),
    (_set(("rlProfiles", 0, "rlProfileCfg_t", "profileId"), [0]), FileFormatError,
     r"\[0\] is not a number"),
    (_set(("rlChirps", 0, "rlChirpCfg_t", "txEnable"), True), FileFormatError,
     r"True is not a number"),
])
def test_studio_json_bad_values_name_the_field(tmp_path, change, error, match):
    with pytest.raises(error, match=match):
        read_ti_cfg(_studio_file(tmp_path, change), board="AWR1843BOOST")


def test_studio_json_advanced_sub_frame_count(tmp_path):
    def advanced(rf):
        del rf["rlFrameCfg_t"]
        rf["waveformType"] = "advancedFrameChirp"
        rf["rlAdvFrameCfg_t"] = {"frameSeq": {"numOfSubFrames": 10 ** 7, "subFrameCfg": []}}
    start = time.perf_counter()
    with pytest.raises(FileFormatError, match=r"numOfSubFrames=10000000.0 must be an integer "
                                              r"in 1..4"):
        read_ti_cfg(_studio_file(tmp_path, advanced), board="AWR1843BOOST")
    assert time.perf_counter() - start < 0.5


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, "[1, 2]", "null"])
def test_studio_json_that_is_not_an_export(tmp_path, text):
    path = tmp_path / "odd.json"
    path.write_text(text)
    with pytest.raises(FileFormatError):
        read_ti_cfg(path, board="AWR1843BOOST")


# The boxes of TI people-tracking ``.cfg`` files (read_boundary_boxes).


def test_boxes_of_the_3d_and_2d_people_tracking_demos(tmp_path):
    cfg = tmp_path / "people.cfg"
    cfg.write_text("sensorStop\n% boxes\nboundaryBox -4 4 0.5 7.5 0 3   % room\n"
                   "staticBoundaryBox -3 3 0.5 7.5 0 3\npresenceBoundaryBox -3 3 0.5 7.5 0 3\n"
                   "boundaryBox -2 1.6 0 3.6 0 2\n")           # the last one counts
    boxes = read_boundary_boxes(cfg)
    assert boxes == {"boundaryBox": (-2.0, 1.6, 0.0, 3.6, 0.0, 2.0),
                     "staticBoundaryBox": (-3.0, 3.0, 0.5, 7.5, 0.0, 3.0),
                     "presenceBoundaryBox": (-3.0, 3.0, 0.5, 7.5, 0.0, 3.0)}
    flat = tmp_path / "pplcount.cfg"
    flat.write_text("boundaryBox -6 6 0.5 10\n")
    assert read_boundary_boxes(flat) == {"boundaryBox": (-6.0, 6.0, 0.5, 10.0)}
    none = tmp_path / "oob.cfg"
    none.write_text("sensorStart\n")
    assert read_boundary_boxes(none) == {}


@pytest.mark.parametrize("line, words", [("boundaryBox -4 4 0.5", "4 or 6 finite numbers"),
                                         ("boundaryBox -4 4 x 7", "must be numbers"),
                                         ("staticBoundaryBox 4 -4 0 7", "minimum must be below"),
                                         ("boundaryBox -4 4 0 nan", "4 or 6 finite")])
def test_bad_boxes_name_the_file_and_line(tmp_path, line, words):
    cfg = tmp_path / "bad.cfg"
    cfg.write_text(f"sensorStop\n{line}\n")
    with pytest.raises(ConfigurationError, match=f"bad.cfg line 2: .*{words}"):
        read_boundary_boxes(cfg)


def test_a_missing_file_is_a_file_format_error(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read"):
        read_boundary_boxes(tmp_path / "none.cfg")


def test_studio_json_with_an_integer_of_5000_digits_names_the_field(tmp_path):
    """Before: Python's int parser refused it with a bare ValueError (over
    4300 digits), which escaped as a traceback."""
    path = _studio_file(tmp_path, _set(("rlFrameCfg_t", "numLoops"), "HUGE"))
    path.write_text(path.read_text().replace('"HUGE"', "1" + "0" * 4999))
    with pytest.raises(ConfigurationError, match=r"numLoops=inf must be a finite number"):
        read_ti_cfg(path, board="AWR1843BOOST")
