"""In-memory model of a recording from a network of radars.

This is the contract between the simulator, the signal chain, calibration,
fusion and the HDF5 file format (:mod:`mmsnap_graph.io`, docs/FORMAT.md): every
layer produces or consumes these values. They are frozen; use
``dataclasses.replace`` (or :meth:`Recording.with_node`) to derive a new one.

Frames are integers counted from 0 at the recording's start; time is
``frame * frame_period_s``. Node-level quantities are in the node's local
frame (docs/CONVENTIONS.md); truth is in the global frame (node S1's frame unless
the recording says otherwise).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ValidationError
from .radar_config import RadarConfig
from .._validation import as_float_array, check_finite, check_pose, int_array

__all__ = ["Detections", "Tracks", "NodeData", "Truth", "Recording", "MIN_FRAME_PERIOD_S",
           "MAX_FRAME_PERIOD_S", "TARGET_MODELS"]

#: ``Recording.targets``: what the radars of a recording see.
TARGET_MODELS = ("people", "points")

#: A recording's frame period bounds (s): a radar frame holds at least one
#: chirp (tens of microseconds), and a frame an hour apart is no tracking.
MIN_FRAME_PERIOD_S = 1e-6
MAX_FRAME_PERIOD_S = 3600.0



def _column(value: ArrayLike, name: str, n: int, *, finite: bool = True) -> NDArray:
    arr = as_float_array(value, name)
    if arr.shape != (n,):
        raise ValidationError(f"{name} must have shape ({n},) like frame, got {arr.shape}")
    return check_finite(arr, name) if finite else arr


def _frames_text(frame: NDArray) -> str:
    """``"K rows, frames a-b"`` of a frame column (a short repr, not the arrays)."""
    if frame.size == 0:
        return "0 rows"
    return f"{frame.size} rows, frames {int(frame.min())}-{int(frame.max())}"


def _pose_text(pose: NDArray | None) -> str:
    if pose is None:
        return "pose unknown"
    return f"pose=({pose[0]:.3f} m, {pose[1]:.3f} m, {pose[2]:.4f} rad)"


@dataclass(frozen=True, kw_only=True, slots=True, repr=False)
class Detections:
    """Detections of one node, one row per detection: a point cloud (many rows
    per frame) or centroids (one row per target per frame).

    frame : (K,) int; range_m, omega_rad, doppler_mps : (K,) float;
    snr_db : (K,) float or None; target_id : (K,) int or None (-1 = unknown,
    e.g. a false alarm or an unlabelled cluster).
    """

    frame: NDArray
    range_m: NDArray
    omega_rad: NDArray
    doppler_mps: NDArray
    snr_db: NDArray | None = None
    target_id: NDArray | None = None

    def __repr__(self) -> str:
        return f"Detections({_frames_text(self.frame)})"

    def __post_init__(self) -> None:
        frame = int_array(self.frame, "frame")
        n = frame.shape[0]
        object.__setattr__(self, "frame", frame)
        for name in ("range_m", "omega_rad", "doppler_mps"):
            object.__setattr__(self, name, _column(getattr(self, name), name, n))
        if self.snr_db is not None:
            object.__setattr__(self, "snr_db", _column(self.snr_db, "snr_db", n))
        if self.target_id is not None:
            tid = int_array(self.target_id, "target_id")
            if tid.shape != (n,):
                raise ValidationError(f"target_id must have shape ({n},), got {tid.shape}")
            object.__setattr__(self, "target_id", tid)
        if np.any(self.range_m < 0):
            raise ValidationError(f"range_m must be >= 0, got {self.range_m.min()!r}")
        if np.any(np.abs(self.omega_rad) > np.pi + 1e-9):
            bad = self.omega_rad[np.argmax(np.abs(self.omega_rad))]
            raise ValidationError(f"omega_rad must lie in [-pi, pi], got {bad!r}")

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    @property
    def measurements(self) -> NDArray:
        """(K, 3) ``(range_m, omega_rad, doppler_mps)`` rows."""
        return np.stack([self.range_m, self.omega_rad, self.doppler_mps], axis=-1)

    def select(self, mask: ArrayLike) -> "Detections":
        """The rows where ``mask`` (boolean or index array) selects."""
        m = np.asarray(mask)
        return Detections(
            frame=self.frame[m],
            range_m=self.range_m[m],
            omega_rad=self.omega_rad[m],
            doppler_mps=self.doppler_mps[m],
            snr_db=None if self.snr_db is None else self.snr_db[m],
            target_id=None if self.target_id is None else self.target_id[m],
        )

    @classmethod
    def empty(cls) -> "Detections":
        z = np.zeros(0)
        return cls(frame=np.zeros(0, np.int64), range_m=z, omega_rad=z, doppler_mps=z)


@dataclass(frozen=True, kw_only=True, slots=True, repr=False)
class Tracks:
    """Tracks of one node in its local frame, one row per track per frame.

    frame, track_id : (K,) int; state : (K, 4) ``(x_m, y_m, vx_mps, vy_mps)``;
    covariance : (K, 4, 4).
    """

    frame: NDArray
    track_id: NDArray
    state: NDArray
    covariance: NDArray

    def __repr__(self) -> str:
        n = np.unique(self.track_id).size
        return f"Tracks({_frames_text(self.frame)}, {n} tracks)"

    def __post_init__(self) -> None:
        frame = int_array(self.frame, "frame")
        n = frame.shape[0]
        tid = int_array(self.track_id, "track_id")
        if tid.shape != (n,):
            raise ValidationError(f"track_id must have shape ({n},) like frame, got {tid.shape}")
        state = check_finite(as_float_array(self.state, "state"), "state")
        if state.shape != (n, 4):
            raise ValidationError(f"state must have shape ({n}, 4), got {state.shape}")
        cov = check_finite(as_float_array(self.covariance, "covariance"), "covariance")
        if cov.shape != (n, 4, 4):
            raise ValidationError(f"covariance must have shape ({n}, 4, 4), got {cov.shape}")
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "track_id", tid)
        object.__setattr__(self, "state", state)
        object.__setattr__(self, "covariance", cov)

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def select(self, mask: ArrayLike) -> "Tracks":
        m = np.asarray(mask)
        return Tracks(frame=self.frame[m], track_id=self.track_id[m], state=self.state[m],
                      covariance=self.covariance[m])

    def track(self, track_id: int) -> "Tracks":
        """The rows of one track, in frame order."""
        rows = np.flatnonzero(self.track_id == track_id)
        return self.select(rows[np.argsort(self.frame[rows], kind="stable")])

    @property
    def track_ids(self) -> NDArray:
        return np.unique(self.track_id)

    @classmethod
    def empty(cls) -> "Tracks":
        return cls(frame=np.zeros(0, np.int64), track_id=np.zeros(0, np.int64),
                   state=np.zeros((0, 4)), covariance=np.zeros((0, 4, 4)))


@dataclass(frozen=True, kw_only=True, slots=True, repr=False)
class NodeData:
    """Everything one node recorded, at each level of the chain.

    name : node name (``"S1"``, ...).
    pose : (3,) ``(x_m, y_m, phi_rad)`` in the global frame when known, else None.
    radar : the chirp configuration of ``cube``.
    cube : (F, n_samples, n_loops, n_virtual) complex raw ADC cubes, or None.
    cube_frame : (F,) int frame numbers of the cubes.
    point_cloud, centroids : :class:`Detections` or None.
    tracks : :class:`Tracks` or None.
    """

    name: str
    pose: NDArray | None = None
    radar: RadarConfig | None = None
    cube: NDArray | None = None
    cube_frame: NDArray | None = None
    point_cloud: Detections | None = None
    centroids: Detections | None = None
    tracks: Tracks | None = None

    def __repr__(self) -> str:
        levels = [f"{name}: {getattr(self, name)!r}" for name in ("point_cloud", "centroids", "tracks")
                  if getattr(self, name) is not None]
        if self.cube is not None:
            levels.insert(0, f"cube: {self.cube.shape[0]} frames of {self.cube.shape[1:]}")
        return f"NodeData({self.name!r}, {_pose_text(self.pose)}" + "".join(", " + x for x in levels) + ")"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or "/" in self.name:
            raise ValidationError(f"node name must be a non-empty string without '/', "
                                  f"got {self.name!r}")
        if self.pose is not None:
            pose = check_pose(self.pose, f"nodes[{self.name}].pose")
            object.__setattr__(self, "pose", pose)
        if self.cube is not None:
            cube = np.asarray(self.cube)
            if self.radar is None:
                raise ValidationError(f"nodes[{self.name}].cube needs its radar configuration")
            if cube.ndim != 4 or cube.shape[1:] != self.radar.cube_shape:
                raise ValidationError(
                    f"nodes[{self.name}].cube must have shape (F, {', '.join(map(str, self.radar.cube_shape))}) "
                    f"for its radar configuration, got {cube.shape}")
            frames = (np.arange(cube.shape[0]) if self.cube_frame is None
                      else int_array(self.cube_frame, f"nodes[{self.name}].cube_frame"))
            if frames.shape != (cube.shape[0],):
                raise ValidationError(f"nodes[{self.name}].cube_frame must have shape "
                                      f"({cube.shape[0]},), got {frames.shape}")
            object.__setattr__(self, "cube", cube)
            object.__setattr__(self, "cube_frame", frames)


@dataclass(frozen=True, kw_only=True, slots=True, repr=False)
class Truth:
    """Ground truth of a simulated (or surveyed) recording, global frame.

    frame, target_id : (T,) int; state : (T, 4) ``(x_m, y_m, vx_mps, vy_mps)``
    of each target's torso at each frame; node_poses : name -> (3,) pose.
    """

    frame: NDArray
    target_id: NDArray
    state: NDArray
    node_poses: Mapping[str, NDArray] = field(default_factory=dict)

    def __repr__(self) -> str:
        n = np.unique(self.target_id).size
        return f"Truth({_frames_text(self.frame)}, {n} targets)"

    def __post_init__(self) -> None:
        frame = int_array(self.frame, "truth.frame")
        n = frame.shape[0]
        tid = int_array(self.target_id, "truth.target_id")
        if tid.shape != (n,):
            raise ValidationError(f"truth.target_id must have shape ({n},), got {tid.shape}")
        state = check_finite(as_float_array(self.state, "truth.state"), "truth.state")
        if state.shape != (n, 4):
            raise ValidationError(f"truth.state must have shape ({n}, 4), got {state.shape}")
        poses = {}
        for name, pose in dict(self.node_poses).items():
            poses[str(name)] = check_pose(pose, f"truth.node_poses[{name}]")
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "target_id", tid)
        object.__setattr__(self, "state", state)
        object.__setattr__(self, "node_poses", poses)

    def target(self, target_id: int) -> tuple[NDArray, NDArray]:
        """``(frame (T,), state (T, 4))`` of one target, in frame order."""
        rows = np.flatnonzero(self.target_id == target_id)
        rows = rows[np.argsort(self.frame[rows], kind="stable")]
        return self.frame[rows], self.state[rows]


@dataclass(frozen=True, kw_only=True, slots=True, repr=False)
class Recording:
    """A recording: nodes (in order; the first is the reference S1), the frame
    period, optional truth, the target model and free-form metadata (str,
    int, float values).

    targets : what the radars see, which sets the calibration's defaults
        (:data:`TARGET_MODELS`): ``"people"`` (bodies whose centroid lies a
        reflection depth nearer each radar than the body's centre; real
        recordings, the simulator's real model) or ``"points"`` (point
        targets, the simulator's clean model). Files that do not declare it
        are read as ``"people"`` (docs/FORMAT.md).
    """

    frame_period_s: float
    nodes: Mapping[str, NodeData]
    truth: Truth | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)
    targets: str = "people"

    def __repr__(self) -> str:
        nodes = ",\n  ".join(repr(node) for node in self.nodes.values())
        truth = "" if self.truth is None else f",\n  {self.truth!r}"
        meta = f",\n  metadata keys: {sorted(self.metadata)}" if self.metadata else ""
        return (f"Recording(frame_period_s={self.frame_period_s:g}, targets {self.targets}, "
                f"{len(self.nodes)} nodes:\n  "
                f"{nodes}{truth}{meta})")

    def __post_init__(self) -> None:
        try:
            fp = math.nan if isinstance(self.frame_period_s, bool) else float(self.frame_period_s)
        except (TypeError, ValueError):
            fp = math.nan
        if not (np.isfinite(fp) and fp > 0):
            raise ValidationError(f"frame_period_s must be finite and > 0, got {self.frame_period_s!r}")
        if not MIN_FRAME_PERIOD_S <= fp <= MAX_FRAME_PERIOD_S:
            raise ValidationError(f"frame_period_s={fp!r} must be in [{MIN_FRAME_PERIOD_S:g}, "
                                  f"{MAX_FRAME_PERIOD_S:g}] s (a unit mistake?)")
        object.__setattr__(self, "frame_period_s", fp)
        nodes = dict(self.nodes)
        if not nodes:
            raise ValidationError("a recording needs at least one node")
        for key, node in nodes.items():
            if not isinstance(node, NodeData) or node.name != key:
                raise ValidationError(f"nodes[{key!r}] must be a NodeData named {key!r}")
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "metadata", dict(self.metadata))
        if self.targets not in TARGET_MODELS:
            raise ValidationError(f"targets={self.targets!r} must be one of "
                                  f"{list(TARGET_MODELS)}")

    @property
    def node_names(self) -> list[str]:
        return list(self.nodes)

    def with_node(self, node: NodeData) -> "Recording":
        """A copy with ``node`` added or replacing the node of the same name."""
        nodes = dict(self.nodes)
        nodes[node.name] = node
        return dataclasses.replace(self, nodes=nodes)

    def node_poses(self) -> dict[str, NDArray | None]:
        """Each node's pose as recorded (None where unknown)."""
        return {name: node.pose for name, node in self.nodes.items()}
