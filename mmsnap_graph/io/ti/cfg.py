"""TI mmWave SDK ``.cfg`` files -> :class:`RadarConfig` (one per sub-frame).

A ``.cfg`` is the list of CLI commands a TI demo reads at start-up, one per
line (``%`` starts a comment). The commands that define the waveform, with the
units TI uses (mmWave SDK user guide, "CLI configuration commands"):

- ``profileCfg id startFreq_GHz idle_us adcStart_us rampEnd_us txPower
  txPhaseShift slope_MHz_per_us txStart_us numAdcSamples sampleRate_ksps
  hpf1 hpf2 rxGain``;
- ``chirpCfg startIdx endIdx profileId startFreqVar slopeVar idleVar
  adcStartVar txEnableMask``;
- ``frameCfg chirpStartIdx chirpEndIdx numLoops numFrames period_ms
  triggerSelect triggerDelay`` (legacy frame);
- ``advFrameCfg numSubFrames forceProfile numFrames triggerSelect
  triggerDelay`` and ``subFrameCfg subFrameNum forceProfileIdx chirpStartIdx
  numOfChirps numLoops burstPeriod_ms chirpStartIdxOffset numOfBurst
  numOfBurstLoops subFramePeriod_ms`` (advanced frame);
- ``channelCfg rxMask txMask cascading``; ``adcCfg numBits outputFmt``
  (0 real, 1 complex 1x, 2 complex 2x); ``adcbufCfg [subFrameIdx] outputFmt
  sampleSwap chanInterleave chirpThreshold`` (0 complex, 1 real);
  ``dfeDataOutputMode`` (1 frame, 3 advanced frame); ``sensorPosition`` of the
  people-tracking demos (mounting height, azimuth and elevation tilt).

The chirps of a frame (or sub-frame) fire their transmitters in order, one
transmitter per chirp (TDM-MIMO); that order becomes the order of the
configuration's transmitters. The antenna positions come from a board preset
(:data:`BOARD_PRESETS`) or an explicit :class:`BoardLayout`: a ``.cfg`` does
not say where the antennas are, and the paper's board is never assumed.

mmWave Studio's JSON export (``*.mmwave.json``: ``mmWaveDevices[0].rfConfig``
with ``rlChanCfg_t``, ``rlAdcOutCfg_t``, ``rlProfiles[].rlProfileCfg_t``,
``rlChirps[].rlChirpCfg_t``, ``rlFrameCfg_t`` or ``rlAdvFrameCfg_t``) holds the
same fields; :func:`read_studio_json` translates it into the equivalent
commands and parses those (errors then name the JSON field).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..._validation import parse_json
from ...data.radar_config import RadarConfig, TiProfile
from ...errors import ConfigurationError, FileFormatError
from .inputs import require_file
from .cfg_fields import cfg_fields

__all__ = ["BoardLayout", "BOARD_PRESETS", "TIMING_ONLY_LAYOUT", "TiConfig", "parse_ti_cfg", "read_ti_cfg",
           "read_boundary_boxes", "BOUNDARY_COMMANDS",
           "board_layout", "studio_json_to_cfg", "read_studio_json"]


@dataclass(frozen=True, kw_only=True, slots=True)
class BoardLayout:
    """Antenna positions of a board in half wavelengths, per *physical*
    transmitter (TX0, TX1, ...) and receiver (RX0, ...). The azimuth array is
    the row of virtual channels at elevation 0."""

    name: str
    tx_azimuth_half_wl: tuple
    tx_elevation_half_wl: tuple
    rx_azimuth_half_wl: tuple
    rx_elevation_half_wl: tuple = ()

    def __post_init__(self) -> None:
        for name in ("tx_azimuth_half_wl", "tx_elevation_half_wl", "rx_azimuth_half_wl",
                     "rx_elevation_half_wl"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        if len(self.tx_azimuth_half_wl) != len(self.tx_elevation_half_wl):
            raise ConfigurationError(f"board {self.name}: tx_azimuth_half_wl and "
                                     "tx_elevation_half_wl differ in length")
        if self.rx_elevation_half_wl and (len(self.rx_elevation_half_wl)
                                          != len(self.rx_azimuth_half_wl)):
            raise ConfigurationError(f"board {self.name}: rx_azimuth_half_wl and "
                                     "rx_elevation_half_wl differ in length")


# Positions follow TI's virtual-antenna tables (the people-tracking demos'
# antGeometry0/1 and the SDK's antenna diagrams) with the azimuth index made
# to grow along the board's x axis; docs/TI.md.
BOARD_PRESETS: dict[str, BoardLayout] = {
    "AWR1843BOOST": BoardLayout(name="AWR1843BOOST", tx_azimuth_half_wl=(0, 2, 4),
                                tx_elevation_half_wl=(0, 1, 0), rx_azimuth_half_wl=(0, 1, 2, 3)),
    "AWR2243BOOST": BoardLayout(name="AWR2243BOOST", tx_azimuth_half_wl=(0, 2, 4),
                                tx_elevation_half_wl=(0, 1, 0), rx_azimuth_half_wl=(0, 1, 2, 3)),
    "IWR6843ISK": BoardLayout(name="IWR6843ISK", tx_azimuth_half_wl=(0, 2, 4),
                              tx_elevation_half_wl=(0, 1, 0), rx_azimuth_half_wl=(0, 1, 2, 3)),
    "IWR6843AOP": BoardLayout(name="IWR6843AOP", tx_azimuth_half_wl=(0, 2, 0),
                              tx_elevation_half_wl=(1, -1, -1), rx_azimuth_half_wl=(1, 1, 0, 0),
                              rx_elevation_half_wl=(0, 1, 0, 1)),
}
BOARD_PRESETS["IWR1843BOOST"] = BOARD_PRESETS["AWR1843BOOST"]

#: A layout for reading a ``.cfg``'s timing only (point clouds): any Tx subset is valid.
TIMING_ONLY_LAYOUT = BoardLayout(name="timing only", tx_azimuth_half_wl=(0.0,) * 16,
                                 tx_elevation_half_wl=(0.0,) * 16, rx_azimuth_half_wl=range(8))

#: Commands that do not change the waveform (processing, monitoring, tracker
#: and GUI settings of the SDK demos); they are accepted and ignored.
IGNORED_COMMANDS = frozenset("""
sensorStop sensorStart flushCfg lowPower guiMonitor cfarCfg multiObjBeamForming calibDcRangeSig
clutterRemoval aoaFovCfg cfarFovCfg compRangeBiasAndRxChanPhase measureRangeBiasAndRxChanPhase
extendedMaxVelocity CQRxSatMonitor CQSigImgMonitor analogMonitor lvdsStreamCfg bpmCfg calibData
peakGrouping nearFieldCfg staticBoundaryBox boundaryBox gatingParam stateParam allocationParam
maxAcceleration trackingCfg presenceBoundaryBox dynamicRACfarCfg staticRACfarCfg
dynamicRangeAngleCfg dynamic2DAngleCfg staticRangeAngleCfg antGeometry0 antGeometry1 antPhaseRot
fovCfg fineMotionCfg clusterCfg idlingCfg SceneryParam GatingParam StateParam AllocationParam
AccelerationParam PresenceBoundaryBox mpdBoundaryBox compressionCfg intfMitigCfg
""".split())

_ARGS = {"profileCfg": (14,), "chirpCfg": (8,), "frameCfg": (7,), "advFrameCfg": (5,),
         "subFrameCfg": (10,), "channelCfg": (3,), "adcCfg": (2,), "adcbufCfg": (4, 5),
         "dfeDataOutputMode": (1,), "sensorPosition": (2, 3, 5)}


@dataclass(frozen=True, kw_only=True, slots=True)
class TiConfig:
    """What a ``.cfg`` says about the waveform.

    configs : one :class:`RadarConfig` per sub-frame (one for a legacy frame).
    n_frames : frames to send (0 = until stopped).
    advanced : the configuration uses ``advFrameCfg``.
    n_rx : enabled receivers. sensor_height_m, azimuth_tilt_rad,
    elevation_tilt_rad : from ``sensorPosition`` when present, else None.
    board : the preset's name (or the explicit layout's).
    ignored : the known non-waveform commands skipped. unknown : the unknown
    commands skipped with ``ignore_unknown=True`` (``"name (line N)"``).
    """

    configs: tuple
    n_frames: int = 0
    advanced: bool = False
    n_rx: int = 4
    sensor_height_m: float | None = None
    azimuth_tilt_rad: float | None = None
    elevation_tilt_rad: float | None = None
    board: str = ""
    ignored: tuple = field(default=())
    unknown: tuple = field(default=())

    @property
    def n_sub_frames(self) -> int:
        return len(self.configs)


def board_layout(board: str | BoardLayout | None, layout: BoardLayout | None = None,
                 *, source: str = "the configuration") -> BoardLayout:
    """The antenna layout from a preset name or an explicit layout; no default."""
    if layout is not None:
        if not isinstance(layout, BoardLayout):
            raise ConfigurationError(f"layout must be a BoardLayout, got {type(layout).__name__}")
        return layout
    if isinstance(board, BoardLayout):
        return board
    if board is None:
        raise ConfigurationError(
            f"{source} does not say where the antennas are: give board= one of "
            f"{sorted(BOARD_PRESETS)} (mmsnap import --board) or an explicit layout")
    key = str(board).upper()
    if key not in BOARD_PRESETS:
        raise ConfigurationError(f"unknown board {board!r}; presets are {sorted(BOARD_PRESETS)}")
    return BOARD_PRESETS[key]


# ---- step 1: lines -> commands ---------------------------------------------------------
@dataclass
class _Line:
    number: int
    command: str
    args: list


class _Commands:
    """The waveform commands of a file, with their line numbers."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.profiles: dict[int, _Line] = {}
        self.chirps: list[_Line] = []
        self.single: dict[str, _Line] = {}
        self.sub_frames: dict[int, _Line] = {}
        self.adcbuf: dict[int, _Line] = {}
        self.ignored: list[str] = []
        self.unknown: list[str] = []

    def error(self, line: _Line | int, message: str) -> ConfigurationError:
        number = line.number if isinstance(line, _Line) else line
        where = f"{self.source} line {number}" if number else self.source
        return ConfigurationError(f"{where}: {message}")


def _numbers(cmds: _Commands, number: int, command: str, words: list[str]) -> list[float]:
    """The arguments as numbers, each finite and within its field's range."""
    try:
        values = [float(w) for w in words]
    except ValueError:
        raise cmds.error(number, f"{command} arguments must be numbers, got "
                                 f"{' '.join(words)!r}") from None
    for (name, integer, low, high), value, word in zip(cfg_fields(command, len(values)), values,
                                                       words):
        if not np.isfinite(value):
            raise cmds.error(number, f"{command} {name}={word} must be a finite number")
        if integer and value != int(value):
            raise cmds.error(number, f"{command} {name}={word} must be an integer")
        if (low is not None and value < low) or (high is not None and value > high):
            raise cmds.error(number, f"{command} {name}={word} must lie in [{low:g}, {high:g}]")
    return values


def _tokenize(text: str, source: str, extra_commands: Iterable[str],
              ignore_unknown: bool = False) -> _Commands:
    cmds = _Commands(source)
    ignored = IGNORED_COMMANDS | frozenset(extra_commands)
    for number, raw in enumerate(text.splitlines(), start=1):
        words = raw.split("%", 1)[0].split()
        if not words:
            continue
        command, rest = words[0], words[1:]
        if command in ignored:
            cmds.ignored.append(command)
            continue
        if command not in _ARGS and ignore_unknown:
            cmds.unknown.append(f"{command} (line {number})")
            continue
        if command not in _ARGS:
            raise cmds.error(number, f"unknown command {command!r} (known: {sorted(_ARGS)} and "
                                     "the processing commands of the SDK demos); to ignore "
                                     "it: mmsnap import --ignore-unknown-commands (in Python "
                                     "extra_commands=[...] or ignore_unknown=True)")
        if len(rest) not in _ARGS[command]:
            raise cmds.error(number, f"{command} takes {' or '.join(map(str, _ARGS[command]))}"
                                     f" arguments, got {len(rest)}")
        _store(cmds, _Line(number, command, _numbers(cmds, number, command, rest)))
    return cmds


def _store(cmds: _Commands, line: _Line) -> None:
    if line.command == "profileCfg":
        pid = int(line.args[0])
        if pid in cmds.profiles:
            raise cmds.error(line, f"profileCfg {pid} is defined again (first on line "
                                   f"{cmds.profiles[pid].number})")
        cmds.profiles[pid] = line
    elif line.command == "chirpCfg":
        cmds.chirps.append(line)
    elif line.command == "subFrameCfg":
        idx = int(line.args[0])
        if idx in cmds.sub_frames:
            raise cmds.error(line, f"subFrameCfg {idx} is defined again")
        cmds.sub_frames[idx] = line
    elif line.command == "adcbufCfg":
        idx = int(line.args[0]) if len(line.args) == 5 else -1
        cmds.adcbuf[idx] = line
    else:
        if line.command in cmds.single:
            raise cmds.error(line, f"{line.command} is given again (first on line "
                                   f"{cmds.single[line.command].number})")
        cmds.single[line.command] = line


# ---- step 2: chirps and masks ----------------------------------------------------------
def _chirp_table(cmds: _Commands) -> dict[int, tuple[_Line, int]]:
    """chirp index -> (its chirpCfg line, transmitter index)."""
    table: dict[int, tuple[_Line, int]] = {}
    for line in cmds.chirps:
        start, end, pid = (int(v) for v in line.args[:3])
        if end < start or start < 0:
            raise cmds.error(line, f"chirpCfg indices {start}..{end} are not increasing")
        if pid not in cmds.profiles:
            raise cmds.error(line, f"chirpCfg refers to profile {pid}, which no profileCfg "
                                   "defines")
        if any(line.args[3:7]):
            raise cmds.error(line, "chirpCfg frequency, slope, idle or ADC-start variations "
                                   "are not supported (all chirps of a frame must be equal)")
        mask = int(line.args[7])
        bits = [b for b in range(8) if mask >> b & 1]
        if len(bits) != 1:
            raise cmds.error(line, f"chirpCfg txEnableMask={mask} must enable exactly one "
                                   "transmitter (TDM-MIMO; BPM or simultaneous Tx is not "
                                   "supported)")
        for idx in range(start, end + 1):
            if idx in table:
                raise cmds.error(line, f"chirp {idx} is already defined on line "
                                       f"{table[idx][0].number}")
            table[idx] = (line, bits[0])
    return table


def _mask_bits(mask: float) -> list[int]:
    m = int(mask)
    return [b for b in range(16) if m >> b & 1]


def _complex_adc(cmds: _Commands, sub_frame: int) -> bool:
    adc = cmds.single.get("adcCfg")
    buf = cmds.adcbuf.get(sub_frame, cmds.adcbuf.get(-1))
    adc_complex = None if adc is None else int(adc.args[1]) != 0
    buf_complex = None if buf is None else int(buf.args[-4]) == 0
    if adc_complex is not None and buf_complex is not None and adc_complex != buf_complex:
        raise cmds.error(buf, f"adcbufCfg says {'complex' if buf_complex else 'real'} samples "
                              f"but adcCfg (line {adc.number}) says "
                              f"{'complex' if adc_complex else 'real'}")
    return True if adc_complex is None and buf_complex is None else bool(
        buf_complex if buf_complex is not None else adc_complex)


# ---- step 3: one (sub-)frame -> RadarConfig --------------------------------------------
def _frame_config(cmds: _Commands, table: dict, where: _Line, first: int, n_chirps: int,
                  n_loops: int, frame_period_s: float, layout: BoardLayout,
                  sub_frame: int) -> RadarConfig:
    chirps = []
    for idx in range(first, first + n_chirps):
        if idx not in table:
            raise cmds.error(where, f"{where.command} uses chirp {idx}, which no chirpCfg "
                                    "defines")
        chirps.append(table[idx])
    txs = [tx for _, tx in chirps]
    if len(set(txs)) != len(txs):
        raise cmds.error(where, f"{where.command} fires transmitters {txs}: a transmitter "
                                "twice in one loop is not TDM-MIMO")
    profiles = {int(line.args[2]) for line, _ in chirps}
    if len(profiles) != 1:
        raise cmds.error(where, f"{where.command} mixes profiles {sorted(profiles)}")
    _check_channels(cmds, where, txs, layout)
    prof = cmds.profiles[profiles.pop()]
    p = prof.args
    rx = _rx_channels(cmds, layout)
    try:
        profile = TiProfile(
            start_freq_hz=p[1] * 1e9, idle_s=p[2] * 1e-6, adc_start_s=p[3] * 1e-6,
            ramp_end_s=p[4] * 1e-6, slope_hz_per_s=p[7] * 1e12, n_samples=int(p[9]),
            sample_rate_hz=p[10] * 1e3, n_loops=n_loops, frame_period_s=frame_period_s,
            complex_adc=_complex_adc(cmds, sub_frame))
        return RadarConfig.from_ti_profile(
            profile,
            tx_azimuth_half_wl=[layout.tx_azimuth_half_wl[t] for t in txs],
            tx_elevation_half_wl=[layout.tx_elevation_half_wl[t] for t in txs],
            rx_azimuth_half_wl=[layout.rx_azimuth_half_wl[r] for r in rx],
            rx_elevation_half_wl=([layout.rx_elevation_half_wl[r] for r in rx]
                                  if layout.rx_elevation_half_wl else ()),
            tx_channels=txs)
    except ConfigurationError as exc:
        raise cmds.error(prof, f"profileCfg {int(p[0])} with {where.command} (line "
                               f"{where.number}): {exc}") from None


def _rx_channels(cmds: _Commands, layout: BoardLayout) -> list[int]:
    ch = cmds.single.get("channelCfg")
    if ch is None:
        raise cmds.error(0, "channelCfg is missing: the enabled receivers are unknown")
    rx = _mask_bits(ch.args[0])
    if not rx or max(rx) >= len(layout.rx_azimuth_half_wl):
        raise cmds.error(ch, f"channelCfg rxChannelEn={int(ch.args[0])} enables receivers "
                             f"{rx}; board {layout.name} has {len(layout.rx_azimuth_half_wl)}")
    return rx


def _check_channels(cmds: _Commands, where: _Line, txs: list[int], layout: BoardLayout) -> None:
    ch = cmds.single.get("channelCfg")
    if ch is None:
        raise cmds.error(where, "channelCfg is missing: the enabled transmitters are unknown")
    enabled = _mask_bits(ch.args[1])
    off = [t for t in txs if t not in enabled]
    if off:
        raise cmds.error(where, f"{where.command} fires TX{off} but channelCfg (line "
                                f"{ch.number}) enables only {['TX%d' % t for t in enabled]}")
    beyond = [t for t in txs if t >= len(layout.tx_azimuth_half_wl)]
    if beyond:
        raise cmds.error(where, f"{where.command} fires TX{beyond}; board {layout.name} has "
                                f"{len(layout.tx_azimuth_half_wl)} transmitters")


def _legacy(cmds: _Commands, table: dict, layout: BoardLayout) -> tuple[list, int]:
    fr = cmds.single["frameCfg"]
    start, end, loops, n_frames = (int(v) for v in fr.args[:4])
    if end < start:
        raise cmds.error(fr, f"frameCfg chirps {start}..{end} are not increasing")
    period_s = fr.args[4] * 1e-3
    return [_frame_config(cmds, table, fr, start, end - start + 1, loops, period_s, layout,
                          0)], n_frames


def _advanced(cmds: _Commands, table: dict, layout: BoardLayout) -> tuple[list, int]:
    adv = cmds.single["advFrameCfg"]
    n_sub, n_frames = int(adv.args[0]), int(adv.args[2])
    missing = [i for i in range(n_sub) if i not in cmds.sub_frames]
    extra = sorted(i for i in cmds.sub_frames if not 0 <= i < n_sub)
    if missing or extra:
        raise cmds.error(adv, f"advFrameCfg declares {n_sub} sub-frames; subFrameCfg "
                              f"missing for {missing}, unexpected for {extra}")
    lines = [cmds.sub_frames[i] for i in range(n_sub)]
    for line in lines:
        bursts, burst_loops = int(line.args[7]), int(line.args[8])
        if bursts != 1 or burst_loops != 1:
            raise cmds.error(line, f"subFrameCfg numOfBurst={bursts}, numOfBurstLoops="
                                   f"{burst_loops}: only one burst per sub-frame is supported")
    period_s = sum(line.args[9] for line in lines) * 1e-3
    configs = [_frame_config(cmds, table, line, int(line.args[2]), int(line.args[3]),
                             int(line.args[4]), period_s, layout, i)
               for i, line in enumerate(lines)]
    return configs, n_frames


def _frame_kind(cmds: _Commands) -> bool:
    """True for an advanced frame; checks that the frame commands agree."""
    legacy, adv = cmds.single.get("frameCfg"), cmds.single.get("advFrameCfg")
    mode = cmds.single.get("dfeDataOutputMode")
    if legacy is not None and adv is not None:
        raise cmds.error(adv, f"advFrameCfg and frameCfg (line {legacy.number}) contradict "
                              "each other: give one")
    if legacy is None and adv is None:
        raise cmds.error(0, "neither frameCfg nor advFrameCfg is given")
    if mode is not None:
        value = int(mode.args[0])
        if value not in (1, 3):
            raise cmds.error(mode, f"dfeDataOutputMode {value} is not supported (1 = frame, "
                                   "3 = advanced frame)")
        if (value == 3) != (adv is not None):
            what = (legacy or adv)
            raise cmds.error(mode, f"dfeDataOutputMode {value} contradicts {what.command} on "
                                   f"line {what.number}")
    if adv is None and cmds.sub_frames:
        line = next(iter(cmds.sub_frames.values()))
        raise cmds.error(line, "subFrameCfg without advFrameCfg")
    return adv is not None


def _sensor_position(cmds: _Commands) -> dict[str, Any]:
    line = cmds.single.get("sensorPosition")
    if line is None:
        return {}
    a = line.args
    height, az, el = (a[0], 0.0, a[1]) if len(a) == 2 else (a[0], a[1], a[2]) if len(a) == 3 \
        else (a[2], a[3], a[4])
    return {"sensor_height_m": float(height), "azimuth_tilt_rad": float(np.deg2rad(az)),
            "elevation_tilt_rad": float(np.deg2rad(el))}


def parse_ti_cfg(text: str, *, board: str | BoardLayout | None = None,
                 layout: BoardLayout | None = None, source: str = "<cfg>",
                 extra_commands: Iterable[str] = (), ignore_unknown: bool = False) -> TiConfig:
    """Parse the text of an mmWave SDK ``.cfg`` (module docstring).

    board : a preset name (:data:`BOARD_PRESETS`) or layout : an explicit
    :class:`BoardLayout`; one of them is required. source : the name used in
    error messages. extra_commands : more command names to ignore.
    ignore_unknown : skip every unknown command (listed in ``TiConfig.unknown``).
    Raises :class:`ConfigurationError` naming the line for unknown commands,
    wrong argument counts and contradictory commands.
    """
    if not isinstance(text, str):
        raise ConfigurationError(f"text must be a str, got {type(text).__name__}")
    lay = board_layout(board, layout, source=source)
    cmds = _tokenize(text, source, extra_commands, bool(ignore_unknown))
    if not cmds.profiles:
        raise cmds.error(0, "no profileCfg is given")
    advanced = _frame_kind(cmds)
    table = _chirp_table(cmds)
    configs, n_frames = (_advanced if advanced else _legacy)(cmds, table, lay)
    return TiConfig(configs=tuple(configs), n_frames=n_frames, advanced=advanced,
                    n_rx=configs[0].n_rx, board=lay.name, ignored=tuple(cmds.ignored),
                    unknown=tuple(cmds.unknown),
                    **_sensor_position(cmds))


def read_ti_cfg(path: str | os.PathLike, *, board: str | BoardLayout | None = None,
                layout: BoardLayout | None = None,
                extra_commands: Iterable[str] = (), ignore_unknown: bool = False) -> TiConfig:
    """Read and parse an mmWave SDK ``.cfg`` file (:func:`parse_ti_cfg`); a
    ``.json`` file is read as an mmWave Studio export (:func:`read_studio_json`)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return read_studio_json(p, board=board, layout=layout)
    require_file(p, "configuration file")
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{p} is not a text file: {exc}") from None
    return parse_ti_cfg(text, board=board, layout=layout, source=str(p.name),
                        extra_commands=extra_commands, ignore_unknown=ignore_unknown)


# ---- mmWave Studio JSON export ---------------------------------------------------------
def _num(value: Any) -> float:
    """JSON numbers, or TI's hex strings (``"0xF"``); anything else (a list,
    an object, true) is a TypeError that names the value."""
    if isinstance(value, str):
        return float(int(value, 0))
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{value!r} is not a number")
    return float(value)


def _fmt(values: Iterable[Any]) -> str:
    """Numbers as ``.cfg`` words; ``repr`` keeps every digit (``nan``/``inf``
    reach the ``.cfg`` checks, which name the field)."""
    return " ".join(repr(_num(v)) for v in values)


def _object(value: Any, path: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise TypeError(f"{path} must be an object, got {type(value).__name__}")
    return value


def _array(value: Any, path: str) -> list:
    if not isinstance(value, list):
        raise TypeError(f"{path} must be an array, got {type(value).__name__}")
    return value


def _studio_lines(rf: Mapping) -> list[tuple[str, str]]:
    """(command line, JSON path) pairs equivalent to an ``rfConfig``."""
    rf = _object(rf, "rfConfig")
    ch = _object(rf["rlChanCfg_t"], "rfConfig.rlChanCfg_t")
    lines = [(f"channelCfg {_fmt([ch['rxChannelEn'], ch['txChannelEn']])} 0",
              "rfConfig.rlChanCfg_t")]
    fmt = _object(rf.get("rlAdcOutCfg_t", {}), "rfConfig.rlAdcOutCfg_t").get("fmt")
    if fmt is not None:
        fmt = _object(fmt, "rfConfig.rlAdcOutCfg_t.fmt")
        lines.append((f"adcCfg {_fmt([fmt['b2AdcBits'], fmt['b2AdcOutFmt']])}",
                      "rfConfig.rlAdcOutCfg_t"))
    for k, item in enumerate(_array(rf["rlProfiles"], "rfConfig.rlProfiles")):
        p = _object(_object(item, f"rfConfig.rlProfiles[{k}]")["rlProfileCfg_t"],
                    f"rfConfig.rlProfiles[{k}].rlProfileCfg_t")
        keys = ("profileId", "startFreqConst_GHz", "idleTimeConst_usec",
                "adcStartTimeConst_usec", "rampEndTime_usec")
        rest = ("freqSlopeConst_MHz_usec", "txStartTime_usec", "numAdcSamples",
                "digOutSampleRate")
        lines.append((f"profileCfg {_fmt(p[key] for key in keys)} 0 0 "
                      f"{_fmt(p.get(key, 0) for key in rest)} 0 0 30",
                      f"rfConfig.rlProfiles[{k}]"))
    for k, item in enumerate(_array(rf["rlChirps"], "rfConfig.rlChirps")):
        c = _object(_object(item, f"rfConfig.rlChirps[{k}]")["rlChirpCfg_t"],
                    f"rfConfig.rlChirps[{k}].rlChirpCfg_t")
        keys = ("chirpStartIdx", "chirpEndIdx", "profileId", "startFreqVar_MHz",
                "freqSlopeVar_KHz_usec", "idleTimeVar_usec", "adcStartTimeVar_usec", "txEnable")
        lines.append((f"chirpCfg {_fmt(c.get(key, 0) for key in keys)}",
                      f"rfConfig.rlChirps[{k}]"))
    lines += _studio_frame(rf)
    return lines


def _studio_frame(rf: Mapping) -> list[tuple[str, str]]:
    kind = str(rf.get("waveformType", "")).lower()
    adv = rf.get("rlAdvFrameCfg_t")
    if "advanced" in kind or (adv is not None and "rlFrameCfg_t" not in rf):
        seq = _object(_object(adv, "rfConfig.rlAdvFrameCfg_t")["frameSeq"],
                      "rfConfig.rlAdvFrameCfg_t.frameSeq")
        n_sub = _num(seq["numOfSubFrames"])
        if not (np.isfinite(n_sub) and 1 <= n_sub <= 4 and n_sub == int(n_sub)):
            raise ValueError(f"rfConfig.rlAdvFrameCfg_t.frameSeq.numOfSubFrames={n_sub!r} must "
                             "be an integer in 1..4")
        subs = _array(seq["subFrameCfg"], "rfConfig.rlAdvFrameCfg_t.frameSeq.subFrameCfg")
        subs = [_object(sub, f"subFrameCfg[{k}]") for k, sub in enumerate(subs[:int(n_sub)])]
        out = [("dfeDataOutputMode 3", "rfConfig.waveformType"),
               (f"advFrameCfg {len(subs)} 0 {_fmt([seq.get('numFrames', 0)])} 1 0",
                "rfConfig.rlAdvFrameCfg_t.frameSeq")]
        keys = ("forceProfileIdx", "chirpStartIdx", "numOfChirps", "numLoops",
                "burstPeriodicity_msec", "chirpStartIdxOffset", "numOfBurst", "numOfBurstLoops",
                "subFramePeriodicity_msec")
        for k, sub in enumerate(subs):
            out.append((f"subFrameCfg {k} {_fmt(sub.get(key, 0) for key in keys)}",
                        f"rfConfig.rlAdvFrameCfg_t.frameSeq.subFrameCfg[{k}]"))
        return out
    f = _object(rf["rlFrameCfg_t"], "rfConfig.rlFrameCfg_t")
    keys = ("chirpStartIdx", "chirpEndIdx", "numLoops", "numFrames", "framePeriodicity_msec")
    return [(f"frameCfg {_fmt(f[key] for key in keys)} 1 0", "rfConfig.rlFrameCfg_t")]


def studio_json_to_cfg(data: Mapping, *, device: int = 0) -> tuple[str, list[str]]:
    """The ``.cfg`` text equivalent to an mmWave Studio JSON export, and the
    JSON path of each of its lines. Raises :class:`FileFormatError` for a
    missing or malformed field."""
    try:
        devices = _object(data, "the file")["mmWaveDevices"]
        dev = devices[device] if isinstance(devices, list) else devices
        pairs = _studio_lines(_object(dev, "mmWaveDevices[]")["rfConfig"])
    except KeyError as exc:
        raise FileFormatError(f"mmWave Studio JSON: missing or malformed field {exc}") from None
    except (IndexError, TypeError, ValueError, OverflowError, AttributeError) as exc:
        raise FileFormatError(f"mmWave Studio JSON: malformed field: {exc}") from None
    return "\n".join(line for line, _ in pairs) + "\n", [path for _, path in pairs]


def read_studio_json(path: str | os.PathLike, *, board: str | BoardLayout | None = None,
                     layout: BoardLayout | None = None, device: int = 0) -> TiConfig:
    """Read an mmWave Studio JSON export (module docstring) like a ``.cfg``."""
    p = Path(path)
    require_file(p, "configuration file")
    try:
        data = parse_json(p.read_text(encoding="utf-8"))
    except ValueError as exc:  # UnicodeDecodeError, json.JSONDecodeError
        raise FileFormatError(f"{p} is not a JSON file: {exc}") from None
    except RecursionError:
        raise FileFormatError(f"{p}: JSON nested too deeply for an mmWave Studio export"
                              ) from None
    text, paths = studio_json_to_cfg(data, device=device)
    try:
        return parse_ti_cfg(text, board=board, layout=layout, source=p.name)
    except ConfigurationError as exc:
        message = re.sub(r"line (\d+)", lambda m: paths[int(m.group(1)) - 1], str(exc))
        raise ConfigurationError(message) from None


#: The people-tracking demos' boxes (x_min, x_max, y_min, y_max, z_min, z_max;
#: metres): ``boundaryBox`` (where tracks may exist), ``staticBoundaryBox``
#: (where a target may stand still), ``presenceBoundaryBox`` (presence
#: detection). The 2D people-counting demo's boxes have four values (no z).
BOUNDARY_COMMANDS = ("boundaryBox", "staticBoundaryBox", "presenceBoundaryBox")


def read_boundary_boxes(path: str | os.PathLike) -> dict[str, tuple[float, ...]]:
    """The boxes of a people-tracking ``.cfg`` (:data:`BOUNDARY_COMMANDS`):
    command -> its 4 or 6 numbers, for the commands present (the last one
    when repeated). The boxes are in the tracker's world frame of that radar
    (origin on the floor below it, ``y`` along its boresight without azimuth
    tilt). Raises :class:`~mmsnap_graph.errors.ConfigurationError` naming the
    file and line of a box that is not 4 or 6 numbers or whose minimum is not
    below its maximum."""
    p = Path(path)
    try:
        text = p.read_text(errors="replace")
    except OSError as exc:
        raise FileFormatError(f"cannot read {p}: {exc.strerror or exc}") from None
    boxes: dict[str, tuple[float, ...]] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        words = raw.split("%", 1)[0].split()
        if not words or words[0] not in BOUNDARY_COMMANDS:
            continue
        where = f"{p} line {number}: {words[0]}"
        try:
            values = tuple(float(w) for w in words[1:])
        except ValueError:
            raise ConfigurationError(f"{where} arguments must be numbers, got "
                                     f"{' '.join(words[1:])!r}") from None
        if len(values) not in (4, 6) or not all(math.isfinite(v) for v in values):
            raise ConfigurationError(f"{where} takes 4 or 6 finite numbers (x_min x_max y_min "
                                     f"y_max [z_min z_max], metres), got {len(values)}")
        if any(values[k] >= values[k + 1] for k in range(0, len(values), 2)):
            raise ConfigurationError(f"{where}: each minimum must be below its maximum, got "
                                     f"{' '.join(words[1:])}")
        boxes[words[0]] = values
    return boxes
