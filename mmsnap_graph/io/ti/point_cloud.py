"""3D point clouds of real radars (TI demos, logs) -> the library's 2D recordings.

:class:`PointCloud3D` holds one node's points in its sensor frame, frame by
frame (TI's convention: x along the array, y boresight, z up on the board).
:func:`cloud_to_detections` projects it into the node's 2D measurement plane
with the node's :class:`Mounting` (height, down tilt, optional height band;
``factors.projection``, docs/TI.md) and :func:`recording_from_point_clouds`
makes a :class:`Recording` with a point-cloud level per node.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.projection import project_to_plane, room_to_sensor
from ..._validation import as_float_array, check_count, int_array
from ...data.recording import Detections, NodeData, Recording
from ...errors import MmsnapWarning, ValidationError

__all__ = ["PointCloud3D", "Mounting", "cloud_to_detections", "recording_from_point_clouds",
           "destack_frames", "accumulate_frames", "check_frame_period", "stamp_unit_factor",
           "beside_fraction"]

_COLUMNS = ("x_m", "y_m", "z_m", "doppler_mps")
#: Limits of a radar point (no mmWave radar sees beyond a few hundred metres
#: or faster than a few hundred m/s): a larger value is a corrupted number.
MAX_COORDINATE_M = 1e4
MAX_SPEED_MPS = 1e3
#: A mounting height beyond this is a unit mistake (centimetres as metres).
MAX_MOUNT_HEIGHT_M = 12.0
#: :func:`accumulate_frames` refuses to make more points than this (memory).
MAX_ACCUMULATED_POINTS = 50_000_000



@dataclass(frozen=True, kw_only=True, slots=True)
class PointCloud3D:
    """One node's 3D points, one row per point.

    frame : (K,) int frame number of each point; x_m, y_m, z_m : (K,) sensor
    frame; doppler_mps : (K,) radial (positive = receding); snr_db, noise_db :
    (K,) or None (NaN where unknown); time_s : (K,) time stamp or None.
    frames : (F,) every frame the source holds, including frames without a
    point (default: the distinct values of ``frame``).
    """

    frame: NDArray
    x_m: NDArray
    y_m: NDArray
    z_m: NDArray
    doppler_mps: NDArray
    snr_db: NDArray | None = None
    noise_db: NDArray | None = None
    time_s: NDArray | None = None
    frames: NDArray | None = None

    def __post_init__(self) -> None:
        frame = int_array(self.frame, "frame")
        n = frame.shape[0]
        object.__setattr__(self, "frame", frame)
        for name in _COLUMNS + ("snr_db", "noise_db", "time_s"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = as_float_array(value, name)
            if arr.shape != (n,):
                raise ValidationError(f"{name} must have shape ({n},) like frame, got {arr.shape}")
            if name in _COLUMNS + ("time_s",) and not np.all(np.isfinite(arr)):
                bad = int(np.flatnonzero(~np.isfinite(arr))[0])
                raise ValidationError(f"{name} must be finite; point {bad} (frame "
                                      f"{frame[bad]}) holds {arr[bad]!r}")
            limit = MAX_SPEED_MPS if name == "doppler_mps" else MAX_COORDINATE_M
            if name in _COLUMNS and arr.size and np.max(np.abs(arr)) > limit:
                bad = int(np.argmax(np.abs(arr)))
                raise ValidationError(f"{name} must lie within +-{limit:g}; point {bad} (frame "
                                      f"{frame[bad]}) holds {float(arr[bad])!r}")
            object.__setattr__(self, name, arr)
        frames = np.unique(frame) if self.frames is None else int_array(self.frames, "frames")
        missing = np.setdiff1d(frame, frames)
        if missing.size:
            raise ValidationError(f"frames lacks frame numbers {missing[:5].tolist()} of points")
        object.__setattr__(self, "frames", frames)

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    @property
    def points_xyz(self) -> NDArray:
        """(K, 3) sensor-frame positions."""
        return np.stack([self.x_m, self.y_m, self.z_m], axis=-1)

    def select(self, mask: ArrayLike) -> "PointCloud3D":
        """The points where ``mask`` selects (``frames`` is kept whole)."""
        m = np.asarray(mask)
        pick = lambda a: None if a is None else a[m]
        return PointCloud3D(frame=self.frame[m], x_m=self.x_m[m], y_m=self.y_m[m],
                            z_m=self.z_m[m], doppler_mps=self.doppler_mps[m],
                            snr_db=pick(self.snr_db), noise_db=pick(self.noise_db),
                            time_s=pick(self.time_s), frames=self.frames)


@dataclass(frozen=True, kw_only=True, slots=True)
class Mounting:
    """How a node is mounted: ``height_m`` above the floor, ``tilt_rad`` down
    tilt (> 0 looks down). ``room_pose`` : the nominal 2D pose ``(x_m, y_m,
    phi_rad)`` a recording tool applied to put the points in a room frame
    (None = the points are in the sensor frame)."""

    height_m: float = 0.0
    tilt_rad: float = 0.0
    room_pose: tuple | None = None

    def __post_init__(self) -> None:
        for name in ("height_m", "tilt_rad"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValidationError(f"{name}={getattr(self, name)!r} must be finite")
            object.__setattr__(self, name, value)
        if abs(self.tilt_rad) >= np.pi / 2:
            raise ValidationError(f"tilt_rad={self.tilt_rad!r} must lie in (-pi/2, pi/2)")
        if abs(self.height_m) > MAX_MOUNT_HEIGHT_M:
            raise ValidationError(f"height_m={self.height_m!r} lies beyond +-{MAX_MOUNT_HEIGHT_M:g}"
                                  f" m: the height is in metres (centimetres? "
                                  f"{self.height_m:g} cm is {self.height_m / 100:g} m)")
        if self.room_pose is not None:
            pose = tuple(float(v) for v in self.room_pose)
            if len(pose) != 3 or not np.all(np.isfinite(pose)):
                raise ValidationError(f"room_pose={self.room_pose!r} must be 3 finite numbers "
                                      "(x_m, y_m, phi_rad)")
            object.__setattr__(self, "room_pose", pose)


def _row_keys(cloud: PointCloud3D, rows: NDArray) -> NDArray:
    """One hashable byte string per point (position, Doppler and SNR when known)."""
    cols = [cloud.x_m[rows], cloud.y_m[rows], cloud.z_m[rows], cloud.doppler_mps[rows]]
    if cloud.snr_db is not None:
        cols.append(np.nan_to_num(cloud.snr_db[rows], nan=-np.inf))
    block = np.ascontiguousarray(np.column_stack(cols))
    return block.view(np.dtype((np.void, block.dtype.itemsize * len(cols)))).ravel()


def _overlap(older: NDArray, newer: NDArray) -> int:
    """Length of the longest head of ``newer`` equal to a tail of ``older``
    (key arrays of two stacks, oldest point first)."""
    if not (older.size and newer.size):
        return 0
    starts = np.flatnonzero(older == newer[0])              # where the head could begin
    for s in starts:                                        # earliest start = longest
        m = older.size - int(s)
        if m <= newer.size and np.array_equal(older[s:], newer[:m]):
            return m
    return 0


#: The deepest stack :func:`destack_frames` looks for (frames per stack), and
#: the frames it reads to find the depth.
MAX_STACK_FRAMES = 64
LAG_FRAMES = 2000


def _stack_lag(heads: list, news: list) -> int:
    """Frames per stack minus one: the lag ``L`` at which the frame a stack
    drops (its oldest, ``heads[k + L]``) is the frame new ``L`` stacks
    earlier (``news[k]``); 0 when no lag fits a non-empty frame."""
    best, best_count = 0, 0
    n = min(len(news), LAG_FRAMES)
    for lag in range(1, min(MAX_STACK_FRAMES, len(heads))):
        count = sum(1 for k in range(min(n, len(heads) - lag))
                    if news[k].size and np.array_equal(heads[k + lag], news[k]))
        if count > best_count:
            best, best_count = lag, count
    return best


def _destack_order(cloud: PointCloud3D, frames: NDArray, reverse: bool):
    """Per present frame (number, rows oldest point first, keys); the rows of
    a stack written newest first are reversed."""
    out = []
    for f in frames:
        rows = np.flatnonzero(cloud.frame == f)
        rows = rows[::-1] if reverse else rows
        out.append((int(f), rows, _row_keys(cloud, rows)))
    return out


def destack_frames(cloud: PointCloud3D, *, frame_period_s: float | None = None) -> PointCloud3D:
    """Undo the stacking of recording tools that store, in each frame, the
    points of the last N frames.

    A frame's stack starts with the tail of the previous frame's stack (the
    frames they share, in order: oldest first, or newest first, whichever
    the cloud's stacks show more of); the points after that overlap are the
    frame's own. Points repeated only by chance (a static reflector giving
    the same quantised point in several frames) are kept: only the shared
    run of points is dropped, never a point because an equal one exists.
    A frame whose number does not follow the previous one shares nothing.
    The stack depth N is found from the frames the stacks drop (the oldest
    frame of stack ``k`` is the frame new in stack ``k - N + 1``), and the
    first stack's N - 1 older frames are given their frame numbers (and,
    with time stamps, times ``frame_period_s`` earlier per frame; the
    stamps' own step when it is None); a first stack that does not split so
    stays whole.
    """
    frames = np.unique(cloud.frame)
    if frames.size < 2:
        return cloud
    best = None
    for reverse in (False, True):
        stacks = _destack_order(cloud, frames, reverse)
        overlaps = [_overlap(a[2], b[2]) if b[0] == a[0] + 1 else 0
                    for a, b in zip(stacks[:-1], stacks[1:])]
        if best is None or sum(overlaps) > sum(best[1]):
            best = (stacks, overlaps)
    stacks, overlaps = best
    keep = np.ones(len(cloud), dtype=bool)
    for (_, rows, _), m in zip(stacks[1:], overlaps):
        keep[rows[:m]] = False
    frame = cloud.frame.copy()
    time = None if cloud.time_s is None else cloud.time_s.copy()
    _recover_first_stack(stacks, overlaps, frame, time, frame_period_s)
    pick = lambda a: None if a is None else a[keep]
    return PointCloud3D(frame=frame[keep], x_m=cloud.x_m[keep], y_m=cloud.y_m[keep],
                        z_m=cloud.z_m[keep], doppler_mps=cloud.doppler_mps[keep],
                        snr_db=pick(cloud.snr_db), noise_db=pick(cloud.noise_db),
                        time_s=pick(time), frames=np.union1d(cloud.frames, frame))


def _recover_first_stack(stacks: list, overlaps: list, frame: NDArray, time: NDArray | None,
                         frame_period_s: float | None) -> None:
    """Renumber (in place) the first stack's older frames: those the next
    stacks drop, when they are its head in order."""
    heads = [a[2][:a[2].size - m] for a, m in zip(stacks[:-1], overlaps)]
    news = [np.zeros(0, stacks[0][2].dtype)] + [b[2][m:] for b, m in zip(stacks[1:], overlaps)]
    lag = _stack_lag(heads, news)
    f0, rows0, keys0 = stacks[0]
    if lag == 0 or len(heads) < lag:
        return
    older = heads[:lag]
    n_older = sum(h.size for h in older)
    if not np.array_equal(np.concatenate(older), keys0[:n_older]):
        return
    if time is not None and frame_period_s is None:
        t = [float(np.median(time[r])) for _, r, _ in stacks]
        f = [s[0] for s in stacks]
        frame_period_s = float(np.median(np.diff(t) / np.diff(f)))
    start = 0
    for j, h in enumerate(older):
        rows = rows0[start:start + h.size]
        frame[rows] = f0 - lag + j
        if time is not None:
            time[rows] -= (lag - j) * frame_period_s
        start += h.size


def accumulate_frames(cloud: PointCloud3D, n_frames: int, *,
                      frame_period_s: float | None = None) -> PointCloud3D:
    """Frame accumulation for sparse clouds: frame ``f`` of the result holds
    the points of frames ``f - n_frames + 1 .. f`` (each point then appears
    in ``n_frames`` frames). Time stamps move with the frame, by
    ``frame_period_s`` per frame, when it is given (else they stay those of
    the original frame: a recording clocked by time stamps would then undo
    the accumulation)."""
    check_count(n_frames, "n_frames")
    if frame_period_s is not None and not (np.isfinite(frame_period_s) and frame_period_s > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
    if len(cloud) * int(n_frames) > MAX_ACCUMULATED_POINTS:
        raise ValidationError(f"n_frames={n_frames} would make {len(cloud)} x {n_frames} "
                              f"points (at most {MAX_ACCUMULATED_POINTS:,})")
    # Oldest first, so that each frame lists its points in time order.
    lags = range(int(n_frames) - 1, -1, -1)
    parts = [(cloud.frame + lag, np.arange(len(cloud)), np.full(len(cloud), lag)) for lag in lags]
    frame = np.concatenate([f for f, _, _ in parts])
    rows = np.concatenate([r for _, r, _ in parts])
    lag = np.concatenate([g for _, _, g in parts])
    inside = frame <= cloud.frames.max() if cloud.frames.size else frame < 0
    order = np.argsort(frame[inside], kind="stable")
    frame, rows, lag = frame[inside][order], rows[inside][order], lag[inside][order]
    pick = lambda a: None if a is None else a[rows]
    time = pick(cloud.time_s)
    if time is not None and frame_period_s is not None:
        time = time + lag * float(frame_period_s)
    return PointCloud3D(frame=frame, x_m=cloud.x_m[rows], y_m=cloud.y_m[rows],
                        z_m=cloud.z_m[rows], doppler_mps=cloud.doppler_mps[rows],
                        snr_db=pick(cloud.snr_db), noise_db=pick(cloud.noise_db),
                        time_s=time, frames=cloud.frames)


def cloud_to_detections(cloud: PointCloud3D, mounting: Mounting = Mounting(), *,
                        height_band_m: tuple[float, float] | None = None,
                        frame_offset: int = 0) -> Detections:
    """Project a node's cloud into its 2D plane (``factors.projection``).

    Points of a room frame are first taken back to the sensor frame with
    ``mounting.room_pose``. ``height_band_m`` drops points outside ``(low,
    high)`` metres above the floor; points on the sensor's vertical are
    dropped. Frame numbers become ``frame - frame_offset``.
    """
    if not isinstance(cloud, PointCloud3D):
        raise ValidationError(f"cloud must be a PointCloud3D, got {type(cloud).__name__}")
    if height_band_m is not None:
        low, high = (float(v) for v in height_band_m)
        if not low < high:
            raise ValidationError(f"height_band_m={height_band_m!r} must be (low, high), low < high")
    xyz = cloud.points_xyz
    if mounting.room_pose is not None:
        xyz = room_to_sensor(xyz, mounting.room_pose, mounting.height_m, mounting.tilt_rad)
    proj = project_to_plane(xyz, cloud.doppler_mps, height_m=mounting.height_m,
                            tilt_rad=mounting.tilt_rad, height_band_m=height_band_m)
    keep = proj.keep
    snr = cloud.snr_db
    use_snr = snr is not None and bool(np.all(np.isfinite(snr[keep])))
    return Detections(frame=cloud.frame[keep] - int(frame_offset), range_m=proj.range_m[keep],
                      omega_rad=proj.omega_rad[keep], doppler_mps=proj.doppler_mps[keep],
                      snr_db=snr[keep] if use_snr else None)


#: A frame period and time stamps disagree when the stamps advance by more than
#: this fraction more or less than the period per frame number.
PERIOD_TOLERANCE = 0.25


def _stamp_frames(clouds: Mapping[str, PointCloud3D], frame_period_s: float,
                  t0: float) -> dict[str, NDArray]:
    """Each node's frame numbers from its time stamps, round((t - t0) / period);
    an error when they do not fit an int64 frame counter (2^53)."""
    out = {}
    for name, c in clouds.items():
        with np.errstate(over="ignore", invalid="ignore"):
            frame = np.round((c.time_s - t0) / frame_period_s)
        if not (np.all(np.isfinite(frame)) and np.max(np.abs(frame)) <= 2 ** 53):
            span = float(c.time_s.max()) - t0
            raise ValidationError(f"node {name}: its time stamps reach {span:.6g} s after the "
                                  f"first one, {span / frame_period_s:.3g} frames of "
                                  f"frame_period_s={frame_period_s!r} s (at most 2^53 frames); "
                                  "check the time stamps and the frame period")
        out[name] = frame.astype(np.int64)
    return out


#: Frames that hold points lying a median of this many frame numbers apart or
#: more: no radar log is that sparse (one frame in 100); the time stamps were
#: read in a unit coarser than theirs (milliseconds as seconds: 1000 apart).
SPARSE_GAP_FRAMES = 100
#: The unit factors a time stamp can be off by (s, ms, us, ns).
_UNIT_FACTORS = (1e-9, 1e-6, 1e-3, 1e3, 1e6, 1e9)


def _stamp_rate(cloud: PointCloud3D) -> tuple[NDArray, float | None]:
    """The distinct frames and the median seconds per frame number of the
    stamps (None with fewer than 3 frames)."""
    frames, inverse, count = np.unique(cloud.frame, return_inverse=True, return_counts=True)
    if frames.size < 3:
        return frames, None
    stamps = np.bincount(inverse, weights=cloud.time_s - float(cloud.time_s.min())) / count
    return frames, float(np.median(np.diff(stamps) / np.diff(frames)))


def stamp_unit_factor(cloud: PointCloud3D, frame_period_s: float) -> float | None:
    """The power of 1000 by which the cloud's time stamps are off their frame
    period, or None when they agree (or no power of 1000 explains it).

    1000 (stamps in milliseconds read as seconds): the stamps advance
    ``1000 x frame_period_s`` per frame number (a frame column, a UART
    header), or the frames numbered from them lie a median of about 1000
    frame numbers apart (no frame column). 0.001 the other way round: the
    stamps advance a thousandth of the period per frame number, or distinct
    stamps of several points each (one per radar frame) lie a thousandth of
    the period apart. Dividing the stamps by the factor makes them agree."""
    if cloud.time_s is None or len(cloud) == 0:
        return None
    near = lambda ratio, factors: next(
        (f for f in factors if abs(np.log10(ratio / f)) < 0.5), None) if ratio > 0 else None
    frames, rate = _stamp_rate(cloud)
    if rate is not None and abs(rate / frame_period_s - 1.0) > PERIOD_TOLERANCE:
        return next((f for f in _UNIT_FACTORS
                     if abs(rate / frame_period_s / f - 1) < PERIOD_TOLERANCE), None)
    if rate is not None and np.median(np.diff(frames)) >= SPARSE_GAP_FRAMES:
        return near(float(np.median(np.diff(frames))), [f for f in _UNIT_FACTORS if f > 1])
    values, counts = np.unique(cloud.time_s, return_counts=True)
    if values.size >= 3 and np.median(counts) >= 2:
        step = float(np.median(np.diff(values))) / frame_period_s
        if step <= 1.0 / SPARSE_GAP_FRAMES:
            return near(step, [f for f in _UNIT_FACTORS if f < 1])
    return None


def check_frame_period(cloud: PointCloud3D, frame_period_s: float, *, node: str = "S1",
                       option: str = "frame_period_s") -> str | None:
    """Why ``frame_period_s`` disagrees with the cloud's time stamps, or None.

    With frame numbers from the source (a frame column, a UART header), the
    stamps must advance by the period per frame number (median over
    consecutive frames, within :data:`PERIOD_TOLERANCE`): stamps coarser
    than the frame (1 s stamps of a 20 fps log) or a period in the wrong unit
    would merge or spread frames. Without distinct frame numbers, distinct
    stamps that each hold several points (one stamp per radar frame) must not
    fall into one frame. ``option`` names the setting in the message.
    """
    if cloud.time_s is None or len(cloud) == 0:
        return None
    t_min = float(cloud.time_s.min())
    frames, rate = _stamp_rate(cloud)
    factor = stamp_unit_factor(cloud, frame_period_s)
    unit = (f"; a factor of {factor:g}: a unit mistake in the time stamps or the frame period?"
            if factor is not None else "")
    if rate is not None and abs(rate / frame_period_s - 1.0) > PERIOD_TOLERANCE:
        distinct = np.unique(cloud.time_s).size
        coarse = (f"; the stamps hold only {distinct} distinct values for {frames.size} "
                  "frames: coarser than a frame" if distinct < frames.size else "")
        return (f"node {node}: {option}={frame_period_s:g} s disagrees with the time stamps, "
                f"which advance {rate:.6g} s per frame number (median of {frames.size - 1} "
                f"frame steps){coarse}{unit}")
    if rate is not None and np.median(np.diff(frames)) >= SPARSE_GAP_FRAMES:
        gap = float(np.median(np.diff(frames)))
        return (f"node {node}: the time stamps put the frames that hold points a median "
                f"{gap:g} frames of {option}={frame_period_s:g} s apart ({gap * frame_period_s:.6g}"
                f" s; {frames.size} frames spread over {frames[-1] - frames[0] + 1} frame "
                f"numbers): no log is that sparse{unit}")
    values, counts = np.unique(cloud.time_s, return_counts=True)
    if values.size >= 3 and np.median(counts) >= 2:
        with np.errstate(over="ignore", invalid="ignore"):
            derived = np.round((values - t_min) / frame_period_s)
        per_frame = np.unique(derived, return_counts=True)[1]
        if np.median(per_frame) >= 2:
            step = float(np.median(np.diff(values)))
            return (f"node {node}: {option}={frame_period_s:g} s merges distinct time stamps "
                    f"{step:.6g} s apart into one frame ({values.size} stamps of several points "
                    f"each fall into {per_frame.size} frames){unit}")
    return None


def _frame_offsets(clouds: Mapping[str, PointCloud3D], frame_period_s: float
                   ) -> tuple[dict[str, PointCloud3D], dict[str, Any]]:
    """Put every node on one frame clock: from time stamps when every cloud
    has them (frame = round((t - t0) / period), t0 = the earliest stamp), else
    each node's frames counted from its first frame (nodes started together)."""
    if all(c.time_s is not None and len(c) for c in clouds.values()):
        for name, c in clouds.items():
            problem = check_frame_period(c, frame_period_s, node=name)
            if problem:
                raise ValidationError(problem)
        t0 = min(float(c.time_s.min()) for c in clouds.values())
        frames = _stamp_frames(clouds, frame_period_s, t0)
        out = {}
        for name, c in clouds.items():
            out[name] = PointCloud3D(frame=frames[name], x_m=c.x_m, y_m=c.y_m, z_m=c.z_m,
                                     doppler_mps=c.doppler_mps, snr_db=c.snr_db,
                                     noise_db=c.noise_db, time_s=c.time_s)
        return out, {"frame_clock": "time_stamps", "time_origin_s": t0}
    out = {}
    for name, c in clouds.items():
        first = int(c.frames.min()) if c.frames.size else 0
        out[name] = PointCloud3D(frame=c.frame - first, x_m=c.x_m, y_m=c.y_m, z_m=c.z_m,
                                 doppler_mps=c.doppler_mps, snr_db=c.snr_db,
                                 noise_db=c.noise_db, time_s=c.time_s, frames=c.frames - first)
    return out, {"frame_clock": "frame_numbers"}


def _no_twins(clouds: Mapping[str, PointCloud3D]) -> None:
    """Two nodes with the same points in the same frames are one log imported
    twice: co-located, identical nodes make every calibration and noise
    estimate degenerate, so they are refused here, where the cause is known."""
    seen: dict[tuple, str] = {}
    for name, c in clouds.items():
        if len(c) == 0:
            continue
        key = (len(c), c.frame.tobytes(), c.x_m.tobytes(), c.y_m.tobytes(), c.z_m.tobytes(),
               c.doppler_mps.tobytes())
        if key in seen:
            raise ValidationError(f"nodes {seen[key]} and {name} hold the same {len(c)} points in "
                                  "the same frames: one log imported twice? (give each node its "
                                  "own log)")
        seen[key] = name


#: A radar sees in front of it (TI's boards: about +-60 degrees of azimuth
#: from the boresight): points beyond this azimuth in the sensor frame...
BESIDE_AZIMUTH_RAD = float(np.deg2rad(75.0))
#: ... are at most this fraction of a node's points (a room pose a quarter
#: or half turn off puts most of them there).
MAX_BESIDE_FRACTION = 0.25
#: Fewer points than this are not judged.
_MIN_VIEW_POINTS = 50


def beside_fraction(points_xyz: NDArray) -> float:
    """The fraction of sensor-frame points ``(K, 3)`` beyond
    :data:`BESIDE_AZIMUTH_RAD` of the boresight (the sensor's y axis), behind
    the radar included."""
    if not len(points_xyz):
        return 0.0
    azimuth = np.arctan2(points_xyz[:, 0], points_xyz[:, 1])
    return float(np.mean(np.abs(azimuth) > BESIDE_AZIMUTH_RAD))


def _view_problem(name: str, cloud: PointCloud3D, mount: Mounting) -> str | None:
    """Why a node's points do not lie in front of it once in its sensor
    frame (a room pose with the boresight's heading, or in radians), or None."""
    xyz = cloud.points_xyz
    if len(xyz) < _MIN_VIEW_POINTS:
        return None
    to_sensor = lambda pose: (room_to_sensor(xyz, pose, mount.height_m, mount.tilt_rad)
                              if pose is not None else xyz)
    beside = beside_fraction(to_sensor(mount.room_pose))
    if beside <= MAX_BESIDE_FRACTION:
        return None
    text = (f"node {name}: {100 * beside:.0f}% of its {len(xyz)} points lie more than "
            f"{np.degrees(BESIDE_AZIMUTH_RAD):.0f} deg from the boresight (beside or behind the "
            "radar) in its sensor frame")
    if mount.room_pose is None:
        return text + ("; a radar sees only in front of it (TI's sensor frame: x along the "
                       "antenna array, y along the boresight; points in a room frame need the "
                       "node's nominal pose, --room-pose)")
    x, y, phi = mount.room_pose
    candidates = {}
    if abs(phi) <= np.deg2rad(2 * np.pi):          # radians typed where degrees are asked
        candidates[f"heading {np.degrees(np.degrees(phi)):.4g} deg (the {np.degrees(phi):.4g} "
                   "given, read as radians)"] = float(np.degrees(phi))
    wrapped = lambda a: (a + np.pi) % (2 * np.pi) - np.pi
    candidates.update({f"heading {np.degrees(wrapped(phi + d)):.4g} deg": phi + d
                       for d in (np.pi / 2, -np.pi / 2, np.pi)})
    fits = {k: beside_fraction(to_sensor((x, y, v))) for k, v in candidates.items()}
    best = next((k for k, f in fits.items() if f <= MAX_BESIDE_FRACTION / 5),
                min(fits, key=fits.get))
    hint = (f"; {best} puts {100 * (1 - fits[best]):.1f}% in front"
            if fits[best] <= MAX_BESIDE_FRACTION else "")
    return (f"{text} once taken back with its room pose (x {x:g} m, y {y:g} m, heading "
            f"{np.degrees(phi):.4g} deg; --room-pose); a radar sees only in front of it: the "
            f"heading is the direction of the antenna array axis, the boresight heading + 90 "
            f"deg{hint}")


def _check_views(clouds: Mapping[str, PointCloud3D], mounts: Mapping[str, Mounting]) -> None:
    """Each node's points in front of it (:func:`_view_problem`, an error);
    a room pose for some nodes but not all warns."""
    for name, cloud in clouds.items():
        problem = _view_problem(name, cloud, mounts[name])
        if problem:
            raise ValidationError(problem)
    rooms = sorted(name for name, m in mounts.items() if m.room_pose is not None)
    if rooms and len(rooms) < len(mounts):
        others = sorted(set(mounts) - set(rooms))
        warnings.warn(f"nodes {rooms} have a room pose, {others} not: the points of {others} are "
                      "taken as in their sensor frames; a logger that writes a room frame "
                      "writes it for every radar (a missing --room-pose?)", MmsnapWarning,
                      stacklevel=3)


def recording_from_point_clouds(clouds: Mapping[str, PointCloud3D], *, frame_period_s: float,
                                mounting: Mounting | Mapping[str, Mounting] = Mounting(),
                                height_band_m: tuple[float, float] | None = None,
                                poses: Mapping[str, ArrayLike] | None = None,
                                metadata: Mapping[str, Any] | None = None,
                                common_frames: bool = False) -> Recording:
    """A :class:`Recording` with a point-cloud level per node.

    clouds : node name -> its cloud, in node order (first = S1).
    mounting : one :class:`Mounting` for all nodes or one per node.
    poses : known 2D node poses (e.g. surveyed), if any.
    common_frames : the clouds' frame numbers are already on one clock, counted
    from the recording's start (live boards stamped by the host,
    :mod:`.serial.timing`): kept as they are.
    """
    if not clouds:
        raise ValidationError("clouds must name at least one node")
    fp = float(frame_period_s)
    if not (np.isfinite(fp) and fp > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
    _no_twins(clouds)
    mounts = {name: mounting[name] if isinstance(mounting, Mapping) else mounting
              for name in clouds}
    _check_views(clouds, mounts)
    if common_frames:
        aligned, md = dict(clouds), {"frame_clock": "host"}
    else:
        aligned, md = _frame_offsets(clouds, fp)
    nodes = {}
    for name, cloud in aligned.items():
        mount = mounts[name]
        det = cloud_to_detections(cloud, mount, height_band_m=height_band_m)
        pose = None if poses is None or name not in poses else poses[name]
        nodes[name] = NodeData(name=name, pose=pose, point_cloud=det)
        md[f"{name}_height_m"] = mount.height_m
        md[f"{name}_tilt_rad"] = mount.tilt_rad
    md.update(dict(metadata or {}))
    return Recording(frame_period_s=fp, nodes=nodes, metadata=md, targets="people")
