"""Bring each node's detections to the reference clock before fusion
(docs/CALIBRATION.md, "Clock offsets").

Convention (docs/FORMAT.md, ``/calibration/time_offset_s``): node time +
offset = reference time. A node with offset ``tau`` took its frame ``f`` at
the reference time ``f T + tau``. Write ``tau = m T + delta`` with ``m =
round(tau / T)`` and ``|delta| <= T / 2``: the detection belongs to the
reference frame ``k = f + m`` and was taken ``delta`` seconds after it. Two
ways to remove ``delta``:

- ``"doppler"`` (any number of detections per frame): the range moves at the
  Doppler speed, ``range(k T) = range - doppler * delta`` (exact to first
  order: the error is half the radial acceleration times ``delta^2``, below
  3 mm for a walker's 1 m/s^2 and ``delta`` = 75 ms). The spatial frequency
  and the Doppler are left as they are: their rates need the tangential
  velocity, which one detection does not give, and estimating it from the
  track's frame differences adds more noise than the drift it removes
  (``pi v_t delta / r``: 0.06 rad for 1 m/s across range at 4 m and the
  largest ``delta``, about the size of one detection's omega noise).
- ``"interpolate"`` (frames with exactly one detection on both sides): the
  three measurements interpolated linearly between the node's frames that
  bracket the reference time (omega along the shorter way round); the error
  is second order in time, and the weighted average of two detections is no
  noisier than one. Other rows fall back to ``"doppler"``.
"""

from __future__ import annotations

import dataclasses
from typing import Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from factors.models import wrap_angle

from ...data.recording import Detections, Recording
from ...errors import ValidationError
from ..._validation import check_positive

__all__ = ["split_offset", "align_detections", "align_recording", "offset_ranges"]


def split_offset(time_offset_s: float, frame_period_s: float) -> tuple[int, float]:
    """``(m, delta)`` with ``time_offset_s = m * frame_period_s + delta``, ``m``
    the nearest whole number of frames and ``|delta| <= frame_period_s / 2``."""
    m = int(np.round(float(time_offset_s) / float(frame_period_s)))
    return m, float(time_offset_s) - m * float(frame_period_s)


def _interpolate(det: Detections, delta: float, frame_period_s: float, range_m: NDArray,
                 omega: NDArray, doppler: NDArray) -> None:
    """Replace, in place, the rows with one detection in their frame and in
    the neighbouring frame on the other side of the reference time."""
    frame = det.frame
    uniq, counts = np.unique(frame, return_counts=True)
    single = uniq[counts == 1]
    step = -1 if delta > 0 else 1  # the neighbour on the other side of k T
    row_of = {int(f): i for i, f in enumerate(frame) if f in set(single.tolist())}
    a = abs(delta) / frame_period_s  # weight of the neighbour
    z = det.measurements
    for f, i in row_of.items():
        j = row_of.get(f + step)
        if j is None:
            continue
        range_m[i] = (1 - a) * z[i, 0] + a * z[j, 0]
        omega[i] = wrap_angle(z[i, 1] + a * wrap_angle(z[j, 1] - z[i, 1]))
        doppler[i] = (1 - a) * z[i, 2] + a * z[j, 2]


def align_detections(detections: Detections, time_offset_s: float, frame_period_s: float, *,
                     method: Literal["doppler", "interpolate"] = "doppler") -> Detections:
    """One node's detections on the reference clock (module doc): frames
    moved by the whole frames of the offset, the measurements brought back by
    the remaining fraction ``delta``."""
    if not isinstance(detections, Detections):
        raise ValidationError(f"detections must be Detections, got {type(detections).__name__}")
    check_positive(frame_period_s, "frame_period_s")
    if not np.isfinite(time_offset_s):
        raise ValidationError(f"time_offset_s={time_offset_s!r} must be finite")
    if method not in ("doppler", "interpolate"):
        raise ValidationError(f"method={method!r} must be 'doppler' or 'interpolate'")
    m, delta = split_offset(time_offset_s, frame_period_s)
    range_m = detections.range_m - detections.doppler_mps * delta
    omega = detections.omega_rad.copy()
    doppler = detections.doppler_mps.copy()
    if method == "interpolate" and delta != 0.0:
        _interpolate(detections, delta, frame_period_s, range_m, omega, doppler)
    return dataclasses.replace(detections, frame=detections.frame + m,
                               range_m=np.abs(range_m), omega_rad=omega, doppler_mps=doppler)


def align_recording(recording: Recording, time_offset_s: Mapping[str, float], *,
                    method: Literal["doppler", "interpolate"] = "doppler") -> Recording:
    """The recording with every node's centroids on the reference clock
    (:func:`align_detections`; a node without an offset keeps its own). Only
    the centroids, which fusion uses, are moved; point clouds and cubes stay
    on the node's clock."""
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    unknown = set(time_offset_s) - set(recording.node_names)
    if unknown:
        raise ValidationError(f"time_offset_s names unknown nodes {sorted(unknown)}")
    nodes = dict(recording.nodes)
    for name, tau in time_offset_s.items():
        node = nodes[name]
        if node.centroids is None or float(tau) == 0.0:
            continue
        nodes[name] = dataclasses.replace(
            node, centroids=align_detections(node.centroids, float(tau),
                                             recording.frame_period_s, method=method))
    return dataclasses.replace(recording, nodes=nodes)


def offset_ranges(recording: Recording, range_offset_m: float) -> Recording:
    """The recording with ``range_offset_m`` added to every centroid's range:
    the calibration's range offset (an extended target's reflection depth,
    docs/CALIBRATION.md, "Extended targets"): each radar's centroid sits that
    much nearer to it than the body's centre, ``range ~ |p - p_i| - d``, so
    the centroid's range plus ``d`` is the centre's."""
    if not isinstance(recording, Recording):
        raise ValidationError(f"recording must be a Recording, got {type(recording).__name__}")
    d = float(range_offset_m)
    if not np.isfinite(d) or abs(d) > 1.0:
        raise ValidationError(f"range_offset_m must be finite metres within +-1 m, got "
                              f"{range_offset_m!r}")
    if d == 0.0:
        return recording
    nodes = {n: (node if node.centroids is None else dataclasses.replace(
        node, centroids=dataclasses.replace(node.centroids, range_m=node.centroids.range_m + d)))
        for n, node in recording.nodes.items()}
    return dataclasses.replace(recording, nodes=nodes)
