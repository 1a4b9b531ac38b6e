"""3D point clouds of real radars (TI demos, logs) -> the library's 2D recordings.

:class:`PointCloud3D` holds one node's points in its sensor frame, frame by
frame (TI's convention: x along the array, y boresight, z up on the board).
:func:`cloud_to_detections` projects it into the node's 2D measurement plane
with the node's :class:`Mounting` (height, down tilt, optional height band;
``factors.projection``, docs/TI.md) and :func:`recording_from_point_clouds`
makes a :class:`Recording` with a point-cloud level per node.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.projection import project_to_plane, room_to_sensor
from ..._validation import as_float_array, check_count, int_array
from ...data.recording import Detections, NodeData, Recording
from ...errors import ValidationError

__all__ = ["PointCloud3D", "Mounting", "cloud_to_detections", "recording_from_point_clouds",
           "destack_frames", "accumulate_frames", "check_frame_period"]

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
    """One hashable byte string per point (position and Doppler)."""
    block = np.ascontiguousarray(np.column_stack([cloud.x_m[rows], cloud.y_m[rows],
                                                  cloud.z_m[rows], cloud.doppler_mps[rows]]))
    return block.view(np.dtype((np.void, block.dtype.itemsize * 4))).ravel()


def destack_frames(cloud: PointCloud3D) -> PointCloud3D:
    """Undo the stacking of recording tools that store, in each frame, the
    points of the last N frames: a point equal (x, y, z, Doppler) to a point
    of the previous frame is dropped, so each point stays in the frame where
    it first appears."""
    keep = np.ones(len(cloud), dtype=bool)
    previous = np.zeros(0, dtype=np.dtype((np.void, 32)))
    last_frame = None
    for f in cloud.frames:
        rows = np.flatnonzero(cloud.frame == f)
        keys = _row_keys(cloud, rows)
        if last_frame is not None and last_frame == f - 1 and previous.size:
            keep[rows] = ~np.isin(keys, previous)
        previous, last_frame = keys, f
    return cloud.select(keep)


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
    frames, inverse, count = np.unique(cloud.frame, return_inverse=True, return_counts=True)
    t_min = float(cloud.time_s.min())
    stamps = np.bincount(inverse, weights=cloud.time_s - t_min) / count    # mean per frame
    if frames.size >= 3:
        rate = np.median(np.diff(stamps) / np.diff(frames))
        if abs(rate / frame_period_s - 1.0) > PERIOD_TOLERANCE:
            distinct = np.unique(cloud.time_s).size
            coarse = (f"; the stamps hold only {distinct} distinct values for {frames.size} "
                      "frames: coarser than a frame" if distinct < frames.size else "")
            ratio = rate / frame_period_s
            unit = next((f"; a factor of {f:g}: a unit mistake in the time stamps or the "
                         "frame period?" for f in (1e-6, 1e-3, 1e3, 1e6)
                         if abs(ratio / f - 1) < PERIOD_TOLERANCE), "")
            return (f"node {node}: {option}={frame_period_s:g} s disagrees with the time stamps, "
                    f"which advance {rate:.6g} s per frame number (median of {frames.size - 1} "
                    f"frame steps){coarse}{unit}")
    values, counts = np.unique(cloud.time_s, return_counts=True)
    if values.size >= 3 and np.median(counts) >= 2:
        with np.errstate(over="ignore", invalid="ignore"):
            derived = np.round((values - t_min) / frame_period_s)
        per_frame = np.unique(derived, return_counts=True)[1]
        if np.median(per_frame) >= 2:
            step = float(np.median(np.diff(values)))
            return (f"node {node}: {option}={frame_period_s:g} s merges distinct time stamps "
                    f"{step:.6g} s apart into one frame ({values.size} stamps of several points "
                    f"each fall into {per_frame.size} frames)")
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


def recording_from_point_clouds(clouds: Mapping[str, PointCloud3D], *, frame_period_s: float,
                                mounting: Mounting | Mapping[str, Mounting] = Mounting(),
                                height_band_m: tuple[float, float] | None = None,
                                poses: Mapping[str, ArrayLike] | None = None,
                                metadata: Mapping[str, Any] | None = None) -> Recording:
    """A :class:`Recording` with a point-cloud level per node.

    clouds : node name -> its cloud, in node order (first = S1).
    mounting : one :class:`Mounting` for all nodes or one per node.
    poses : known 2D node poses (e.g. surveyed), if any.
    """
    if not clouds:
        raise ValidationError("clouds must name at least one node")
    fp = float(frame_period_s)
    if not (np.isfinite(fp) and fp > 0):
        raise ValidationError(f"frame_period_s={frame_period_s!r} must be finite and > 0")
    _no_twins(clouds)
    aligned, md = _frame_offsets(clouds, fp)
    nodes = {}
    for name, cloud in aligned.items():
        mount = mounting[name] if isinstance(mounting, Mapping) else mounting
        det = cloud_to_detections(cloud, mount, height_band_m=height_band_m)
        pose = None if poses is None or name not in poses else poses[name]
        nodes[name] = NodeData(name=name, pose=pose, point_cloud=det)
        md[f"{name}_height_m"] = mount.height_m
        md[f"{name}_tilt_rad"] = mount.tilt_rad
    md.update(dict(metadata or {}))
    return Recording(frame_period_s=fp, nodes=nodes, metadata=md, targets="people")
