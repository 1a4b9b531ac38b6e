"""Import of TI DCA1000EVM / mmWave Studio raw ADC captures (``adc_data.bin``).

Byte layout implemented (xWR12xx / xWR14xx / AWR2243 class devices with the
DCA1000EVM, complex 1x ADC output, 4 LVDS lanes, as written by mmWave Studio's
post-processing into the header-free ``adc_data.bin``; TI application report
SWRA581 "Mmwave Radar Device ADC Raw Data Capture", section "xWR12xx and
xWR14xx With DCA1000 Data Format" and its MATLAB reader):

1. The file is a stream of little-endian ``int16`` values.
2. The values come in groups of four, ``I[k], I[k+1], Q[k], Q[k+1]``: two
   consecutive complex samples ``k, k+1`` of the complex stream ("2I followed
   by 2Q"), ``x = I + jQ`` (``iq_swap=True`` reads ``Q + jI`` for devices
   configured to send Q first).
3. The complex stream holds chirp after chirp; within a chirp, receiver after
   receiver (RX0 ... RX{n_rx-1}, the enabled receivers in order); within a
   receiver, the ``n_samples`` ADC samples in time order. So complex sample
   ``k`` of a frame is ``((chirp * n_rx) + rx) * n_samples + n``.
4. Chirps follow the TDM-MIMO frame: loop after loop, and within a loop the
   transmitters in firing order (the order of ``RadarConfig``'s transmitters,
   i.e. the chirp configurations from the frame's start to end index):
   ``chirp = loop * n_tx + tx``.
5. Frames follow each other with no header or padding. Captures split into
   several files (``adc_data_0.bin``, ``adc_data_1.bin``, ... ; mmWave Studio
   splits at 1 GB, anywhere in a frame) are read as one stream, in order.

The imported cube has the project's layout ``(F, n_samples, n_loops,
n_tx * n_rx)`` complex64 with virtual channel ``tx * n_rx + rx``
(:mod:`mmsnap_graph.data.radar_config`). Raw ``adc_data_Raw_N.bin`` files (with
the DCA1000's UDP packet headers) must first be converted by mmWave Studio's
post-processing.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_count
from ..._atomic import atomic_path
from ...errors import ConfigurationError, FileFormatError, ValidationError
from ...data.radar_config import RadarConfig
from ...data.recording import NodeData, Recording
from .inputs import require_file

__all__ = ["MAX_LVDS_RECEIVERS", "frame_bytes", "read_dca1000_bin", "iter_dca1000_frames",
           "write_dca1000_bin", "recording_from_dca1000", "sub_frame_layout",
           "read_dca1000_sub_frame", "describe_files"]

#: The DCA1000's LVDS interface carries at most four receivers.
MAX_LVDS_RECEIVERS = 4
_INT16 = np.dtype("<i2")


def _check_config(config: RadarConfig) -> None:
    if not isinstance(config, RadarConfig):
        raise ConfigurationError(f"config must be a RadarConfig, got {type(config).__name__}")
    if not config.complex_adc:
        raise ConfigurationError("config has complex_adc=False: real-ADC DCA1000 captures are "
                                 "not supported (configure complex 1x output)")
    if config.n_rx > MAX_LVDS_RECEIVERS:
        raise ConfigurationError(f"config has n_rx={config.n_rx} receivers; a DCA1000 capture "
                                 f"holds at most {MAX_LVDS_RECEIVERS}")
    per_frame = config.n_loops * config.n_tx * config.n_rx * config.n_samples
    if per_frame % 2:
        raise ConfigurationError(
            f"a frame of {per_frame} complex samples (n_loops={config.n_loops} x n_tx="
            f"{config.n_tx} x n_rx={config.n_rx} x n_samples={config.n_samples}) is odd; the "
            "2I-2Q packing of the capture needs an even count per frame")


def frame_bytes(config: RadarConfig) -> int:
    """Bytes of one frame in the capture: 2 (I, Q) x 2 bytes per complex sample."""
    _check_config(config)
    return 4 * config.n_loops * config.n_tx * config.n_rx * config.n_samples


def _paths(path: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    if isinstance(path, (str, os.PathLike)):
        paths = [Path(path)]
    else:
        paths = [Path(p) for p in path]
    if not paths:
        raise FileFormatError("no capture file given")
    for p in paths:
        require_file(p, "capture file")
    return paths


def _decode(raw: NDArray, config: RadarConfig, iq_swap: bool) -> NDArray:
    """int16 values of whole frames -> (F, n_samples, n_loops, n_virtual) complex64."""
    quad = raw.reshape(-1, 2, 2).astype(np.float32)          # (pairs, I/Q, k/k+1)
    re, im = (quad[:, 1], quad[:, 0]) if iq_swap else (quad[:, 0], quad[:, 1])
    z = np.empty(re.shape, dtype=np.complex64)
    z.real = re
    z.imag = im
    n_l, n_t, n_r, n_s = config.n_loops, config.n_tx, config.n_rx, config.n_samples
    z = z.reshape(-1, n_l, n_t, n_r, n_s)                       # (F, loop, tx, rx, sample)
    return np.ascontiguousarray(z.transpose(0, 4, 1, 2, 3).reshape(-1, n_s, n_l, n_t * n_r))


class _Stream:
    """Several capture files read as one byte stream."""

    def __init__(self, paths: list[Path]) -> None:
        self.paths = paths
        self.sizes = [p.stat().st_size for p in paths]
        self.total = sum(self.sizes)

    def read(self, start: int, n: int) -> bytes:
        out = bytearray()
        offset = 0
        for p, size in zip(self.paths, self.sizes):
            if start < offset + size and start + n > offset:
                lo = max(start - offset, 0)
                hi = min(start + n - offset, size)
                with open(p, "rb") as fh:
                    fh.seek(lo)
                    chunk = fh.read(hi - lo)
                if len(chunk) != hi - lo:
                    raise FileFormatError(f"{p} ended early while reading bytes {lo}:{hi}")
                out += chunk
            offset += size
        return bytes(out)


def describe_files(paths: Sequence[Path], *, limit: int = 3) -> str:
    """A short description of a capture's files: all of them up to ``limit``,
    else the count, the first and the last."""
    if len(paths) <= limit:
        return ", ".join(str(p) for p in paths)
    return f"{len(paths)} files {paths[0]} ... {paths[-1]}"


@dataclass(frozen=True, slots=True)
class _Layout:
    """Where a frame's bytes sit: frame k at ``offset + k * stride``, ``size`` bytes."""

    offset: int
    stride: int
    size: int


def _layout(config: RadarConfig, offset_bytes: int, stride_bytes: int | None) -> _Layout:
    fb = frame_bytes(config)
    stride = fb if stride_bytes is None else stride_bytes
    for name, value in (("offset_bytes", offset_bytes), ("stride_bytes", stride)):
        check_count(value, name, 0)
    if offset_bytes % 4 or stride % 4:
        raise ValidationError(f"offset_bytes={offset_bytes} and stride_bytes={stride} must be "
                              "multiples of 4 (one complex int16 sample)")
    if offset_bytes + fb > stride:
        raise ConfigurationError(
            f"a frame of {fb} bytes at offset_bytes={offset_bytes} does not fit in "
            f"stride_bytes={stride}")
    return _Layout(int(offset_bytes), int(stride), fb)


def _frame_count(stream: _Stream, config: RadarConfig, *, allow_partial_frame: bool,
                 layout: _Layout | None = None) -> int:
    lay = layout or _layout(config, 0, None)
    where = describe_files(stream.paths)
    if stream.total == 0:
        raise FileFormatError(f"capture {where} is empty")
    if stream.total % 2:
        raise FileFormatError(f"capture {where} has {stream.total} bytes, not a whole number "
                              "of int16 values")
    n, rest = divmod(stream.total, lay.stride)
    unit = (f"frames of {lay.stride} bytes" if lay.stride == lay.size else
            f"frames of {lay.stride} bytes (stride; the selected sub-frame is {lay.size} "
            f"bytes at offset {lay.offset})")
    if rest and not allow_partial_frame:
        raise FileFormatError(
            f"capture {where} has {stream.total} bytes = {n} whole {unit} + {rest} bytes: "
            f"truncated, or the chirp configuration (n_samples={config.n_samples}, n_loops="
            f"{config.n_loops}, n_tx={config.n_tx}, n_rx={config.n_rx}) differs from the "
            f"capture's (expected a multiple of {lay.stride} bytes). Check the configuration "
            "first: with a wrong one every frame decodes wrong bytes; only for a capture cut "
            "short, allow_partial_frame=True (mmsnap import dca1000 --allow-partial-frame) "
            "drops the incomplete last frame")
    if rest:
        warnings.warn(f"capture {where}: dropped the incomplete last frame ({rest} of "
                      f"{lay.stride} bytes)", stacklevel=3)
    if n == 0:
        raise FileFormatError(f"capture {where} holds {stream.total} bytes, less than one frame "
                              f"of {lay.stride} bytes for this chirp configuration")
    return n


def _read_frames(stream: _Stream, lay: _Layout, start: int, stop: int) -> NDArray:
    if lay.stride == lay.size:
        raw = stream.read(start * lay.size, (stop - start) * lay.size)
    else:
        block = stream.read(start * lay.stride, (stop - start) * lay.stride)
        raw = b"".join(block[k * lay.stride + lay.offset:k * lay.stride + lay.offset + lay.size]
                       for k in range(stop - start))
    return np.frombuffer(raw, dtype=_INT16)


def iter_dca1000_frames(path: str | os.PathLike | Sequence[str | os.PathLike],
                        config: RadarConfig, *, chunk_frames: int = 16, iq_swap: bool = False,
                        allow_partial_frame: bool = False, offset_bytes: int = 0,
                        stride_bytes: int | None = None
                        ) -> Iterator[tuple[NDArray, NDArray]]:
    """Yield ``(frame (n,), cube (n, n_samples, n_loops, n_virtual) complex64)``
    chunks of a capture without loading it whole (layout: module docstring;
    ``offset_bytes``/``stride_bytes`` as in :func:`read_dca1000_bin`)."""
    check_count(chunk_frames, "chunk_frames")
    _check_config(config)
    lay = _layout(config, offset_bytes, stride_bytes)
    stream = _Stream(_paths(path))
    n = _frame_count(stream, config, allow_partial_frame=allow_partial_frame, layout=lay)
    for start in range(0, n, int(chunk_frames)):
        stop = min(start + int(chunk_frames), n)
        yield np.arange(start, stop), _decode(_read_frames(stream, lay, start, stop), config,
                                              iq_swap)


def read_dca1000_bin(path: str | os.PathLike | Sequence[str | os.PathLike],
                     config: RadarConfig, *, n_frames: int | None = None,
                     iq_swap: bool = False, allow_partial_frame: bool = False,
                     offset_bytes: int = 0, stride_bytes: int | None = None) -> NDArray:
    """Read a DCA1000 / mmWave Studio capture into ``(F, n_samples, n_loops,
    n_tx * n_rx)`` complex64 (layout: module docstring).

    path : one ``adc_data.bin`` or the ordered list of its split parts.
    config : the chirp configuration the capture was made with (of the
        selected sub-frame for an advanced frame).
    n_frames : the number of frames expected; :class:`FileFormatError` if the
        capture holds a different number (None = whatever it holds).
    iq_swap : the device sent Q before I.
    allow_partial_frame : drop an incomplete last frame (with a warning)
        instead of raising; only right for a capture cut short.
    offset_bytes, stride_bytes : frame k is read at ``offset_bytes + k *
        stride_bytes`` (default: consecutive frames); for one sub-frame of an
        advanced frame use :func:`sub_frame_layout` or
        :func:`read_dca1000_sub_frame`. The capture must hold whole strides.
    Raises :class:`ConfigurationError` for a configuration a DCA1000 capture
    cannot have, :class:`FileFormatError` for missing, empty or truncated
    files and sizes that do not match the configuration.
    """
    _check_config(config)
    lay = _layout(config, offset_bytes, stride_bytes)
    stream = _Stream(_paths(path))
    n = _frame_count(stream, config, allow_partial_frame=allow_partial_frame, layout=lay)
    if n_frames is not None and n != n_frames:
        raise FileFormatError(f"capture holds {n} frames of {lay.stride} bytes, "
                              f"expected n_frames={n_frames}")
    return _decode(_read_frames(stream, lay, 0, n), config, iq_swap)


def sub_frame_layout(configs: Sequence[RadarConfig], sub_frame: int) -> tuple[int, int]:
    """``(offset_bytes, stride_bytes)`` of one sub-frame in an advanced-frame
    capture whose frames hold the sub-frames ``configs`` in order."""
    configs = list(getattr(configs, "configs", configs))
    if not configs:
        raise ConfigurationError("configs must hold at least one sub-frame configuration")
    if int(sub_frame) != sub_frame or not 0 <= sub_frame < len(configs):
        raise ValidationError(f"sub_frame={sub_frame!r} must be in 0..{len(configs) - 1} "
                              "(mmsnap import dca1000 --sub-frame)")
    sizes = [frame_bytes(c) for c in configs]
    return int(sum(sizes[:int(sub_frame)])), int(sum(sizes))


def read_dca1000_sub_frame(path: str | os.PathLike | Sequence[str | os.PathLike],
                           configs: Sequence[RadarConfig], sub_frame: int, *,
                           n_frames: int | None = None, iq_swap: bool = False,
                           allow_partial_frame: bool = False) -> NDArray:
    """Read one sub-frame of an advanced-frame capture (``configs``: one per
    sub-frame, in order, e.g. ``TiConfig.configs``; offset and stride follow
    from their sizes, :func:`sub_frame_layout`)."""
    configs = list(getattr(configs, "configs", configs))
    offset, stride = sub_frame_layout(configs, sub_frame)
    return read_dca1000_bin(path, configs[int(sub_frame)], n_frames=n_frames, iq_swap=iq_swap,
                            allow_partial_frame=allow_partial_frame, offset_bytes=offset,
                            stride_bytes=stride)


def write_dca1000_bin(path: str | os.PathLike, cube: ArrayLike, config: RadarConfig, *,
                      iq_swap: bool = False) -> Path:
    """Write cubes ``(F, n_samples, n_loops, n_virtual)`` in the capture layout
    (the inverse of :func:`read_dca1000_bin`; values rounded to int16, which
    must hold them). Atomic. For tests and for exporting simulated captures."""
    _check_config(config)
    c = np.asarray(cube)
    if c.ndim != 4 or c.shape[1:] != config.cube_shape:
        raise ValidationError(f"cube must have shape (F, {', '.join(map(str, config.cube_shape))}),"
                              f" got {c.shape}")
    re, im = np.round(c.real), np.round(c.imag)
    lim = np.iinfo(np.int16)
    if (re.size and (min(re.min(), im.min()) < lim.min or max(re.max(), im.max()) > lim.max)):
        raise ValidationError("cube values exceed the int16 range of a capture")
    n_f = c.shape[0]
    n_l, n_t, n_r, n_s = config.n_loops, config.n_tx, config.n_rx, config.n_samples
    # (F, S, L, T*R) -> (F, L, T, R, S) -> flat complex stream -> pairs.
    order = lambda a: a.reshape(n_f, n_s, n_l, n_t, n_r).transpose(0, 2, 3, 4, 1).reshape(-1, 2)
    i_part, q_part = (order(im), order(re)) if iq_swap else (order(re), order(im))
    quad = np.stack([i_part, q_part], axis=1).astype(_INT16)     # (pairs, I/Q, k/k+1)
    path = Path(path)
    with atomic_path(path) as tmp:
        quad.tofile(tmp)
    return path


def recording_from_dca1000(captures: Mapping[str, str | os.PathLike | Sequence],
                           config: RadarConfig | Mapping[str, RadarConfig], *,
                           poses: Mapping[str, ArrayLike] | None = None,
                           iq_swap: bool = False, allow_partial_frame: bool = False,
                           metadata: Mapping | None = None,
                           sub_frame: int | None = None) -> Recording:
    """A :class:`Recording` of raw cubes from one capture per node.

    captures : node name -> capture path (or its split parts), in node order
        (first = S1). config : one configuration for all or one per node.
    poses : known node poses, if any. Frames are numbered from 0 in each
    capture (captures are assumed to start together). sub_frame : for
    advanced-frame captures, the sub-frame to read; ``config`` is then the
    sequence of sub-frame configurations (or a ``TiConfig``), for all nodes or
    one per node.
    """
    nodes = {}
    for name, path in captures.items():
        cfg = config[name] if isinstance(config, Mapping) else config
        if sub_frame is None:
            cube = read_dca1000_bin(path, cfg, iq_swap=iq_swap,
                                    allow_partial_frame=allow_partial_frame)
        else:
            cfg = list(getattr(cfg, "configs", cfg))
            cube = read_dca1000_sub_frame(path, cfg, sub_frame, iq_swap=iq_swap,
                                          allow_partial_frame=allow_partial_frame)
            cfg = cfg[int(sub_frame)]
        pose = None if poses is None or name not in poses else poses[name]
        nodes[name] = NodeData(name=name, pose=pose, radar=cfg, cube=cube,
                               cube_frame=np.arange(cube.shape[0]))
    if not nodes:
        raise FileFormatError("captures must name at least one node")
    first = next(iter(nodes.values())).radar
    md = {"source": "dca1000"}
    md.update(dict(metadata or {}))
    return Recording(frame_period_s=first.frame_period_s, nodes=nodes, metadata=md,
                     targets="people")
