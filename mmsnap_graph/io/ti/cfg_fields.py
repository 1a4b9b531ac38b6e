"""The arguments of the TI ``.cfg`` waveform commands: names, integer or not,
and ranges (used by :mod:`mmsnap_graph.io.ti.cfg` to check every number)."""

from __future__ import annotations

__all__ = ["cfg_fields", "cfg_fields_table"]

#: Per command, each argument's name, whether it is an integer, and its range
#: (TI's hardware limits, mmWave SDK user guide and the radar interface
#: control document: at most 512 chirps in the chirp table, 255 loops, 4
#: sub-frames, a frame period of 5 ns x 2^28 = 1342 ms). An argument outside
#: its range is an error naming it: a huge chirp index would otherwise make
#: the parser walk millions of chirps.
_I, _F = True, False
_FIELDS: dict[str, tuple] = {
    "profileCfg": (("profileId", _I, 0, 15), ("startFreq", _F, 1.0, 300.0),
                   ("idleTime", _F, 0.0, 5242.87), ("adcStartTime", _F, 0.0, 4095.0),
                   ("rampEndTime", _F, 0.0, 5000.0), ("txOutPower", _F, None, None),
                   ("txPhaseShifter", _F, None, None), ("freqSlopeConst", _F, -1000.0, 1000.0),
                   ("txStartTime", _F, -1000.0, 1000.0), ("numAdcSamples", _I, 2, 16384),
                   ("digOutSampleRate", _F, 1.0, 100000.0), ("hpfCornerFreq1", _F, None, None),
                   ("hpfCornerFreq2", _F, None, None), ("rxGain", _F, None, None)),
    "chirpCfg": (("startIdx", _I, 0, 511), ("endIdx", _I, 0, 511), ("profileId", _I, 0, 15),
                 ("startFreqVar", _F, None, None), ("freqSlopeVar", _F, None, None),
                 ("idleTimeVar", _F, None, None), ("adcStartTimeVar", _F, None, None),
                 ("txEnableMask", _I, 0, 255)),
    "frameCfg": (("chirpStartIdx", _I, 0, 511), ("chirpEndIdx", _I, 0, 511),
                 ("numLoops", _I, 1, 255), ("numFrames", _I, 0, 65535),
                 ("framePeriodicity", _F, 0.001, 1342.18), ("triggerSelect", _F, None, None),
                 ("frameTriggerDelay", _F, None, None)),
    "advFrameCfg": (("numOfSubFrames", _I, 1, 4), ("forceProfile", _F, None, None),
                    ("numFrames", _I, 0, 65535), ("triggerSelect", _F, None, None),
                    ("frameTrigDelay", _F, None, None)),
    "subFrameCfg": (("subFrameNum", _I, 0, 3), ("forceProfileIdx", _F, None, None),
                    ("chirpStartIdx", _I, 0, 511), ("numOfChirps", _I, 1, 512),
                    ("numLoops", _I, 1, 255), ("burstPeriodicity", _F, 0.0, 1342.18),
                    ("chirpStartIdxOffset", _F, None, None), ("numOfBurst", _I, 1, 512),
                    ("numOfBurstLoops", _I, 1, 64), ("subFramePeriodicity", _F, 0.001, 1342.18)),
    "channelCfg": (("rxChannelEn", _I, 1, 255), ("txChannelEn", _I, 1, 255),
                   ("cascading", _F, None, None)),
    "adcCfg": (("numADCBits", _I, 0, 2), ("adcOutputFmt", _I, 0, 2)),
    "dfeDataOutputMode": (("modeType", _I, 1, 3),),
}
_ADCBUF = (("subFrameIdx", _I, -1, 3), ("adcOutputFmt", _I, 0, 1), ("SampleSwap", _F, None, None),
           ("ChanInterleave", _F, None, None), ("ChirpThreshold", _F, None, None))
_SENSOR = {2: (("height", _F, -100.0, 100.0), ("elevationTilt", _F, -90.0, 90.0)),
           3: (("height", _F, -100.0, 100.0), ("azimuthTilt", _F, -180.0, 180.0),
               ("elevationTilt", _F, -90.0, 90.0)),
           5: (("xOffset", _F, None, None), ("yOffset", _F, None, None),
               ("height", _F, -100.0, 100.0), ("azimuthTilt", _F, -180.0, 180.0),
               ("elevationTilt", _F, -90.0, 90.0))}


def cfg_fields(command: str, n_args: int) -> tuple:
    """``(name, integer, low, high)`` of each of the ``n_args`` arguments of a
    waveform command (``low``/``high`` None: any finite number)."""
    if command == "adcbufCfg":
        return _ADCBUF[-n_args:]
    if command == "sensorPosition":
        return _SENSOR[n_args]
    return _FIELDS[command]


#: TI's unit of each bounded argument (the ``.cfg`` is in TI's units, not SI).
_UNITS = {"startFreq": "GHz", "idleTime": "us", "adcStartTime": "us", "rampEndTime": "us",
          "freqSlopeConst": "MHz/us", "txStartTime": "us", "numAdcSamples": "samples",
          "digOutSampleRate": "ksps", "framePeriodicity": "ms", "burstPeriodicity": "ms",
          "subFramePeriodicity": "ms", "height": "m", "azimuthTilt": "deg",
          "elevationTilt": "deg", "numLoops": "loops", "numFrames": "frames (0: endless)",
          "numOfChirps": "chirps", "numOfBurst": "bursts", "numOfBurstLoops": "loops"}


def _span(integer: bool, low: float, high: float, unit: str | None) -> str:
    text = f"{low:g}..{high:g}" if integer else f"[{low:g}, {high:g}]"
    return text + (f" {unit}" if unit else "")


def cfg_fields_table() -> str:
    """The bounded arguments of each command as a Markdown table, for
    docs/TI.md (the tests check that it is quoted there): one row per
    command, ``name range unit``; a whole number's range as ``low..high``, a
    real one's as ``[low, high]``. Arguments not listed take any finite
    number."""
    commands = [(c, f) for c, f in _FIELDS.items()]
    commands += [("adcbufCfg", _ADCBUF), ("sensorPosition", _SENSOR[5])]
    rows = ["| command | bounded arguments (TI's units; whole numbers as low..high) |",
            "|---------|------------------------------------------------------------|"]
    for command, fields in commands:
        spans = [f"`{name}` {_span(integer, low, high, _UNITS.get(name))}"
                 for name, integer, low, high in fields if low is not None]
        rows.append(f"| `{command}` | {'; '.join(spans)} |")
    return "\n".join(rows) + "\n"
