"""What a run does, apart from the command line that asks for it.

The ``mmsnap`` commands and the batch runner (:mod:`mmsnap_graph.app.batch`)
call the same functions here, so a recording calibrated or fused by ``mmsnap
batch`` is the one ``mmsnap calibrate`` and ``mmsnap fuse`` write:

- :func:`stored_calibration`: the ONE place that reads what ``mmsnap
  calibrate`` stored for the commands that fuse (``fuse``, ``monitor``,
  ``replay``, the batch's fuse step): the poses (a calibration JSON, else
  the recording's), their covariances, the nodes' clock offsets and the
  measurement noise (``--sigmas``, else the ``/noise`` group, else the
  paper's), with what each is in words;
- :func:`calibrate_and_store`: calibrate a recording file and store the
  result (calibration JSON, node poses, ``/calibration``, ``/noise``),
  warning of poses far from the nominal ones given at import
  (:func:`nominal_texts`, also ``mmsnap monitor``'s);
- :func:`fuse_stored`: fuse a recording file window by window with its
  stored calibration and a :class:`~mmsnap_graph.fusion.config.FusionConfig`,
  and write ``/fused``.

GTSAM, h5py and the estimators are imported inside the functions: the
command-line parser imports this module and must stay light.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import MmsnapWarning

if TYPE_CHECKING:
    from ..fusion.config import FusionConfig
    from ..fusion.options import NetworkCalibration

__all__ = [
    "nominal_texts",
    "StoredCalibration",
    "stored_calibration",
    "paper_noise",
    "calibration_json_path",
    "calibration_poses_for",
    "check_calibration_nodes",
    "calibrate_and_store",
    "fuse_stored",
    "range_offset_for_poses",
]



@dataclass(frozen=True, kw_only=True, slots=True)
class StoredCalibration:
    """What fusion takes from a recording's calibration, read once.

    node_poses : name -> ``(x_m, y_m, phi_rad)`` from a calibration JSON;
        None: the poses stored on the recording's nodes.
    pose_covariances : name -> (3, 3) body-tangent covariance of each
        calibrated pose, or None (poses taken as exact).
    time_offset_s : name -> the node's clock offset (node time + offset =
        reference time), or None (clocks as recorded).
    range_offset_m : the calibration's range offset (reflection depth, m),
        added to every centroid range before fusion; None: none.
    noise : one :class:`~mmsnap_graph.data.noise.MeasurementNoise`, or one
        per node (name -> noise), or None when neither ``--sigmas`` nor a
        ``/noise`` group gave one (the caller's default applies).
    text : what each of them is, in words, one line each.
    """

    node_poses: Mapping[str, np.ndarray] | None = None
    pose_covariances: Mapping[str, np.ndarray] | None = None
    time_offset_s: Mapping[str, float] | None = None
    noise: Any = None
    text: tuple[str, ...] = field(default_factory=tuple)
    range_offset_m: float | None = None

    def network_calibration(self) -> NetworkCalibration:
        """The parts fusion takes, as one
        :class:`~mmsnap_graph.fusion.options.NetworkCalibration` (empty
        mappings as None)."""
        from ..fusion.options import NetworkCalibration

        return NetworkCalibration(
            node_poses=None if self.node_poses is None else dict(self.node_poses),
            pose_covariances=dict(self.pose_covariances) if self.pose_covariances else None,
            time_offset_s=dict(self.time_offset_s) if self.time_offset_s else None,
            range_offset_m=None if self.range_offset_m is None else float(self.range_offset_m))

    def with_default_noise(self, noise, text: str) -> "StoredCalibration":
        """This calibration with ``noise`` (said as ``text``) where it has
        none (``noise`` None: the estimator's own default, said so)."""
        if self.noise is not None:
            return self
        return replace(self, noise=noise, text=(text,) + self.text[1:])


def check_calibration_nodes(calibration_json: str | os.PathLike, poses: Mapping[str, Any],
                            node_names: Sequence[str]) -> None:
    """The one rule of a calibration JSON given to a command (fuse, replay,
    monitor, noise, evaluate): it holds a pose for every node of the
    recording; else :class:`~mmsnap_graph.errors.CalibrationError` naming
    the nodes it lacks (never the recording's own pose used silently)."""
    from ..errors import CalibrationError

    missing = [n for n in node_names if n not in poses]
    if missing:
        raise CalibrationError(f"{calibration_json} has no pose for node(s) {missing} of the "
                               f"recording (it has {sorted(poses)}); every node needs one")


def calibration_poses_for(calibration_json: str | os.PathLike, node_names: Sequence[str]
                          ) -> dict[str, np.ndarray]:
    """The poses of a calibration JSON for a recording's nodes
    (:func:`check_calibration_nodes`)."""
    from ..io.calibration import load_calibration_poses

    poses = load_calibration_poses(calibration_json)
    check_calibration_nodes(calibration_json, poses, node_names)
    return poses


def _read_calibration(path, calibration_json):
    """``calibration_json`` when given, else the recording's ``/calibration``
    group, else None."""
    import h5py

    from ..io.calibration import CALIBRATION_GROUP, read_calibration, read_calibration_json

    if calibration_json:
        return read_calibration_json(calibration_json)
    with h5py.File(path, "r") as f:
        if CALIBRATION_GROUP not in f:
            return None
    return read_calibration(path)


def _noise(path, node_names, sigmas, per_node):
    from ..data.noise import MeasurementNoise
    from ..io.noise import read_noise

    if sigmas is not None:
        r, w, v = sigmas
        return MeasurementNoise(range_m=r, omega_rad=w, doppler_mps=v), "sigmas from --sigmas"
    if path is None:
        return None, "no recording's /noise group"
    if read_noise(path) is None:
        return None, "no /noise group (run `mmsnap calibrate` or `mmsnap noise`)"
    from ..io.noise import noise_for_fusion

    return noise_for_fusion(path, node_names, per_node=per_node)


def stored_calibration(path: str | os.PathLike, node_names: Sequence[str], *,
                       calibration_json: str | os.PathLike | None = None,
                       sigmas: Sequence[float] | None = None,
                       pose_covariances: bool | str = True,
                       time_offsets: bool = True,
                       per_node_noise: bool = True) -> StoredCalibration:
    """What ``mmsnap calibrate`` stored, as every command that fuses uses it.

    path : the recording; node_names : its nodes (for the noise). None with
        ``calibration_json`` (``mmsnap live``: no recording yet): no
        ``/noise`` sigmas (the paper's unless ``sigmas``), no stored range
        offset.
    calibration_json : poses, covariances and clock offsets from this file
        instead of the recording's ``/calibration`` group.
    sigmas : ``(range_m, omega_rad, doppler_mps)`` for every node, instead
        of the ``/noise`` group.
    pose_covariances : include the poses' covariances (True), or not (False,
        or a string saying why not, printed).
    time_offsets : bring each node to the reference clock with its offset.
    per_node_noise : one noise per node from ``/noise`` (False: pooled).
    """
    noise, noise_text = _noise(path, node_names, sigmas, per_node_noise)
    text = [noise_text]
    cal = _read_calibration(path, calibration_json)
    if calibration_json:
        check_calibration_nodes(calibration_json, cal.poses, node_names)
    if cal is None:
        text.append("no calibration: poses exact, clocks as recorded")
        return StoredCalibration(noise=noise, text=tuple(text))
    covs = {n: np.asarray(c, dtype=float) for n, c in cal.covariances.items()
            if np.all(np.isfinite(c)) and np.any(np.asarray(c) != 0)}
    used_covs, parts = None, []
    if isinstance(pose_covariances, str):
        parts.append(pose_covariances)
    elif not pose_covariances:
        parts.append("poses exact")
    elif not covs:
        parts.append("poses exact (the calibration has no pose covariance)")
    else:
        used_covs = covs
        parts.append(f"pose covariances of {', '.join(sorted(covs))} included")
    offsets = {n: float(t) for n, t in cal.time_offset_s.items() if float(t) != 0}
    if offsets and time_offsets:
        parts.append("clock offsets applied: " + ", ".join(
            f"{n} {1e3 * t:+.1f} ms" for n, t in sorted(offsets.items())))
    else:
        offsets = {}
        parts.append("clocks as recorded")
    poses = ({n: np.asarray(p, dtype=float) for n, p in cal.poses.items()}
             if calibration_json else None)
    depth = float(cal.range_offset_m)
    if np.isfinite(depth):
        parts.append(f"range offset (reflection depth) {depth:.3f} m added to every range")
    elif poses is not None and path is not None:
        depth, said, here = _stored_range_offset(path, cal)
        parts += [said] if said else []
        if said and not here and sigmas is None:
            parts.append(f"the /noise sigmas are those of the last `mmsnap calibrate` or "
                         f"`mmsnap noise`: `mmsnap noise {Path(path).name} --calibration "
                         f"{Path(calibration_json).name}` estimates them and the range offset "
                         "at these poses")
    text.append("; ".join(parts))
    return StoredCalibration(node_poses=poses, pose_covariances=used_covs,
                             time_offset_s=offsets or None, noise=noise, text=tuple(text),
                             range_offset_m=depth if np.isfinite(depth) else None)


def _stored_range_offset(path, calibration) -> tuple[float, str, bool]:
    """The range offset to add when fusing at ``calibration``'s poses (a
    calibration JSON without one), read, never estimated here (fusion reads
    no more than a window at a time): none at the recording's own calibrated
    poses (they took any depth in); else the one ``mmsnap noise
    --calibration`` stored with the noise at those poses. Returns (offset or
    NaN, words, whether the stored noise is of these poses)."""
    from ..io.noise import read_range_offset

    own = _read_calibration(path, None)
    if own is not None and _same_poses(own.poses, calibration.poses):
        return float("nan"), "", False
    stored = read_range_offset(path)
    if stored is not None and _same_poses(stored.poses, calibration.poses):
        return stored.offset_m, stored.message, True
    return float("nan"), ("the calibration gives no range offset and none was estimated at "
                          "these poses: none added"), False


def range_offset_for_poses(path: str | os.PathLike, calibration, noise, *,
                           recording=None) -> tuple[float, str]:
    """The range offset (reflection depth, m) to add to every centroid range
    of the recording at ``path`` when fusing at ``calibration``'s poses
    (a calibration JSON, read), and what it is in words ("" when nothing is
    to say): the calibration's own when it has one; none at the recording's
    own calibrated poses (they took any depth in); else the one the
    cross-node residuals identify at those fixed poses
    (:func:`~mmsnap_graph.calibration.noise.depth.range_offset_at_poses`,
    weighted by ``noise``: one :class:`MeasurementNoise`, one per node, or
    None for the paper's), NaN where it is not identified.
    ``recording``: the recording already read (else read here)."""
    from ..calibration.noise.depth import range_offset_at_poses
    from ..io import read_recording

    depth = float(calibration.range_offset_m)
    if np.isfinite(depth):
        return depth, f"range offset (reflection depth) {depth:.3f} m added to every range"
    own = _read_calibration(path, None)
    if own is not None and _same_poses(own.poses, calibration.poses):
        return float("nan"), ""
    rec = recording if recording is not None else read_recording(path, load_cubes=False)
    est = range_offset_at_poses(rec, calibration.poses,
                                noise=paper_noise()[0] if noise is None else noise,
                                lag_frames=calibration.lag_frames)
    if not est.identified:
        return float("nan"), est.message + "; none added"
    return est.offset_m, (f"the calibration gives no range offset: {est.message}, added to "
                          f"every range")


def _same_poses(a, b, tol: float = 1e-6) -> bool:
    return set(a) == set(b) and all(
        np.allclose(np.asarray(a[n], float), np.asarray(b[n], float), atol=tol, rtol=0.0)
        for n in a)


def paper_noise():
    """The paper's sigmas and what they are in words: the noise of a
    recording without ``/noise`` and without ``--sigmas``."""
    from ..data.noise import MeasurementNoise

    return MeasurementNoise(), ("no /noise group (run `mmsnap calibrate` or `mmsnap noise`): "
                                "the paper's sigmas 0.035 m, pi/4 rad, 0.1807 m/s")


def calibration_json_path(recording: str | os.PathLike) -> Path:
    """Where a calibration's JSON goes by default: next to the recording,
    ``<stem>.calibration.json``."""
    p = Path(recording)
    return p.with_name(p.stem + ".calibration.json")


def calibrate_and_store(path: str | os.PathLike,
                        options: Mapping[str, Any] | Callable[[Any], Mapping] | None = None, *,
                        output: str | os.PathLike | None = None,
                        json_path: str | os.PathLike | None = None,
                        write: bool = True, on_result=None, progress: bool = False,
                        overwrite: bool = False, window_s: float | None = None):
    """Calibrate the recording at ``path`` and store the result.

    options : keyword arguments of
        :func:`~mmsnap_graph.calibration.calibrate_recording`, or a function
        of the recording read that returns them (an option that depends on
        the recording, e.g. a lag window in frames, or the joint graph's
        options over :func:`~mmsnap_graph.calibration.joint_options_for`
        it); left out, each takes ``calibrate_recording``'s default.
    output : write a copy of the recording here (default: update ``path``).
    json_path : the calibration JSON (default :func:`calibration_json_path`
        of the recording written).
    write : store the node poses, ``/calibration`` and ``/noise`` in the
        recording (False: the JSON only).
    on_result : called with the calibration before anything is written
        (``mmsnap calibrate`` prints it).
    progress : a tqdm bar over the steps (read, calibrate, write) on stderr.
    overwrite : replace an existing calibration JSON (default: refuse it,
        :class:`~mmsnap_graph.errors.FileFormatError` before anything is
        read; a hand-edited file is never lost silently). The recording
        itself is updated in place either way.
    window_s : calibrate window by window, windows of this many seconds
        read from the file, their poses combined
        (:func:`~mmsnap_graph.calibration.joint.windowed.calibrate_windowed`:
        memory bounded by a window, not the recording); None: by
        :func:`~mmsnap_graph.calibration.joint.windowed.window_frames_for`,
        windows of 600 s for a recording longer than 20 minutes, else one
        solve (``inf``: one solve always). ``options`` as a function is
        then given the first window's recording.
    The recording is locked from the read to the last write. Returns
    ``(calibration, files written)``.
    """
    from .._atomic import recording_lock, refuse_existing
    from ..calibration import calibrate_recording
    from ..calibration.joint.windowed import calibrate_windowed, window_frames_for
    from ..io import read_recording
    from ..io.chunks import open_detection_windows
    from ..io.calibration import write_calibration, write_calibration_json
    from ..io.noise import write_noise
    from tqdm import tqdm

    json_path = Path(json_path) if json_path else calibration_json_path(output or path)
    refuse_existing(json_path, overwrite=overwrite)
    written: list[Path] = []
    bar = tqdm(total=3, desc="calibrate: reading", unit="step", disable=not progress,
               leave=False)
    with bar, recording_lock(path):
        index = open_detection_windows(path)
        frames = window_frames_for(max(index.last_frame - index.first_frame + 1, 0),
                                   index.frame_period_s, window_s)
        if frames is None:
            rec = read_recording(path, load_cubes=False)
            kwargs = options(rec) if callable(options) else dict(options or {})
            bar.set_description("calibrate: matching, pose graph, joint graph, noise")
            bar.update()
            cal = calibrate_recording(rec, **kwargs)
        else:
            first, _ = index.read(*next(index.windows(frames)))
            kwargs = options(first) if callable(options) else dict(options or {})
            bar.set_description(f"calibrate: windows of {frames} frames")
            bar.update()
            cal = calibrate_windowed(index, frames, **kwargs)
            rec = read_recording(path, load_cubes=False)   # what the writes keep
        bar.set_description("calibrate: writing")
        bar.update()
        bar.clear()
        if on_result is not None:
            on_result(cal)
        for text in nominal_texts(rec.metadata, cal.poses, reference=cal.reference):
            warnings.warn(text, MmsnapWarning, stacklevel=2)
        written.append(Path(write_calibration_json(json_path, cal)))
        if write:
            dst = Path(write_calibration(path, rec, cal, output=output))
            if cal.noise is not None:  # the noise from the data, for fusion
                with recording_lock(dst):
                    write_noise(dst, cal.noise)
            written.append(dst)
        bar.update()
    return cal, written


def fuse_stored(path: str | os.PathLike, config: FusionConfig | None = None, *,
                output: str | os.PathLike | None = None,
                calibration: StoredCalibration | None = None,
                progress: bool | None = False):
    """Fuse the recording at ``path`` window by window
    (:func:`~mmsnap_graph.app.chunked_fuse.fuse_file`) with its stored
    calibration and write ``/fused`` (in ``path``, or a copy at ``output``).

    config : the :class:`~mmsnap_graph.fusion.config.FusionConfig` (default
        :data:`~mmsnap_graph.fusion.config.DEFAULT_CONFIG`, as ``mmsnap fuse``).
    calibration : what to fuse with (default :func:`stored_calibration` of
        the file, every part used); no noise in it: the paper's.
    The recording is locked from the read to the write. Returns ``(summary,
    calibration used)``.
    """
    from .._atomic import recording_lock
    from ..fusion.config import DEFAULT_CONFIG
    from ..io.chunks import open_detection_windows
    from .chunked_fuse import fuse_file

    config = DEFAULT_CONFIG if config is None else config
    with recording_lock(path):
        if calibration is None:
            names = open_detection_windows(path, source=config.association.source).node_names
            calibration = stored_calibration(
                path, names, pose_covariances=config.solve.covariance == "laplace")
        calibration = calibration.with_default_noise(*paper_noise())
        summary = fuse_file(path, config, output=output, progress=progress,
                            calibration=calibration.network_calibration(),
                            noise=calibration.noise)
    return summary, calibration


_CAUSES = {
    "boresight": "the headings differ by about 90 deg: was the boresight's direction given? "
                 "The heading is the direction of the antenna array axis, the boresight "
                 "heading + 90 deg",
    "reversed": "the headings differ by about 180 deg: the radar faces the other way from its "
                "nominal pose",
    "radians": "the nominal heading is the calibrated one in radians: radians typed where "
               "degrees are asked?",
    "room_frame": "it was calibrated at the reference's own place and heading: its points "
                  "were already in a frame common to both (a room-frame log imported without "
                  "--room-pose for this node?)",
    "unknown": "check the nominal pose, the mounting and the recording",
}


def nominal_texts(metadata: Mapping[str, Any], poses: Mapping[str, Any], *,
                  reference: str) -> list[str]:
    """The warnings of calibrated ``poses`` far from the nominal poses in a
    recording's ``metadata``, and of nodes calibrated at one place
    (:mod:`mmsnap_graph.evaluation.nominal`), worded with the likely cause."""
    from ..evaluation.nominal import coincident_nodes, nominal_poses, pose_departures

    nominal = nominal_poses(metadata, list(poses))
    departures = pose_departures(poses, nominal, reference=reference)
    out = []
    for d in departures:
        x, y, phi = d.nominal
        heading = float(np.degrees(phi)) if np.degrees(phi) > -179.95 else 180.0
        option = "--room-pose" if d.source == "room_pose" else "--pose"
        out.append(f"{d.node} was calibrated {d.distance_m:.2f} m and "
                   f"{np.degrees(d.heading_error_rad):+.1f} deg from its nominal pose ({option}: "
                   f"x {x:.2f} m, y {y:.2f} m, heading {heading:.1f} deg in "
                   f"{reference}'s frame): {_CAUSES[d.cause]}")
    far = {d.node for d in departures}
    for c in coincident_nodes(poses):
        if {c.node_a, c.node_b} & far:
            continue                                    # said above
        out.append(f"{c.node_a} and {c.node_b} were calibrated {c.distance_m:.2f} m and "
                   f"{np.degrees(c.heading_difference_rad):+.1f} deg apart: two radars at one "
                   "place looking the same way? Points already in one room frame calibrate to "
                   "this: import such a log with --room-pose for every node")
    return out
