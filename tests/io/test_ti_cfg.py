"""``.cfg`` and mmWave Studio JSON numbers (mmsnap_graph.io.ti_cfg): every bad
number, shape or nesting is a ConfigurationError or FileFormatError naming the
field, in well under a second; the Studio JSON sample reads like its .cfg."""

from __future__ import annotations

import copy
import json
import time

import numpy as np
import pytest

from mmsnap_graph.app.cli import main
from mmsnap_graph.errors import ConfigurationError, FileFormatError, MmsnapError
from mmsnap_graph.io import read_recording
from mmsnap_graph.io.ti_cfg import parse_ti_cfg, read_ti_cfg
from ti_samples import DCA_CFG, FAST_CFG, studio_json

from _shared import TI_DATA


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
    a = read_ti_cfg(TI_DATA / "dca1000_fast.mmwave.json", board="AWR1843BOOST")
    b = read_ti_cfg(TI_DATA / "dca1000_fast.cfg", board="AWR1843BOOST")
    assert a.configs == b.configs
    assert json.loads((TI_DATA / "dca1000_fast.mmwave.json").read_text()) == studio_json()
    assert main(["import", "dca1000", "--cfg", str(TI_DATA / "dca1000_fast.mmwave.json"),
                 "--board", "AWR1843BOOST", "--node", f"S1={TI_DATA / 'dca1000_fast.bin'}",
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
    (_set(("rlFrameCfg_t", "numLoops"), 10 ** 400), FileFormatError, r"malformed field"),
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
