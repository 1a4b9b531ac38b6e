"""One configuration of recording fusion: :class:`FusionConfig`.

A recording is fused by one pipeline (:mod:`mmsnap_graph.fusion.recording.pipeline`):
the association of each frame's detections into targets, the one-shot solve of
each target, then the checks. Each stage is a component with its own frozen
options; a check that is not in :attr:`FusionConfig.checks` does not run (no
on/off flags):

- :class:`AssociationOptions`: the association gate, the detections fused and
  the merge of one body's centroids;
- the solve: :class:`~mmsnap_graph.fusion.options.FusionOptions` (solver,
  covariance, Levenberg-Marquardt settings), the prior (None: maximum
  likelihood) and the robust fit (:class:`~mmsnap_graph.fusion.options.RobustOptions`);
- the checks, run in this order: :class:`MotionCheck` (each row against the
  motion of its neighbouring frames), :class:`SplitCheck` (one-node rows of a
  frame the association split), :class:`CoverageCheck` (rows a radar that
  covers their place never sees), :class:`UnplacedCheck` (one-node rows
  no walk ties to a row of two nodes), :class:`RoomCheck` (room bounds, in front of
  the radars, static bounds), :class:`LearnedWalls` (beyond a wall learned from
  multipath images) and :class:`DuplicateCheck` (one body seen twice).

Each check says how far it looks around a row (:attr:`look_frames`); the
pipeline's drivers read that: the windowed driver reads that many frames of
context around each window, the stream decides a frame once it has seen that
many frames after it (or, with less delay, from the frames it has: causally).

The same :class:`FusionConfig` is built from the ``mmsnap`` flags, the
``[fuse]`` table of a ``--config`` TOML file and ``mmsnap batch``
(:func:`mmsnap_graph.app.commands.arguments.fusion_config`). GTSAM-free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar, Literal, Mapping

import numpy as np

from ..data.body import BODY_WIDTH_M, CENTROID_MERGE_RADIUS_M
from ..data.noise import GaussianPrior
from .._validation import check_count, check_probability
from ..errors import ValidationError
from .options import DEFAULT_OPTIONS, FusionOptions, RobustOptions, robust_options
from .recording.motion_check import MOTION_CONTEXT_FRAMES, MOTION_WINDOW_FRAMES
from .recording.room import RoomBounds
from .recording.unplaced import UNPLACED_LOOK_AHEAD_FRAMES, UNPLACED_LOOK_BACK_FRAMES

__all__ = ["AssociationOptions", "MotionCheck", "SplitCheck", "CoverageCheck", "RoomCheck",
           "UnplacedCheck", "LearnedWalls", "DuplicateCheck", "CHECKS", "DEFAULT_CHECKS", "FusionConfig",
           "DEFAULT_CONFIG", "PLAIN_CONFIG", "WHOLE_RECORDING"]

#: :attr:`look_frames` of a check that looks at the whole recording.
WHOLE_RECORDING = -1


def _positive_m(value: object, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)) or not (math.isfinite(value)
                                                                 and value > 0):
        raise ValidationError(f"{name} must be a positive finite number of metres, got {value!r}")
    return float(value)


@dataclass(frozen=True, kw_only=True, slots=True)
class AssociationOptions:
    """Which detections of one frame are one target
    (:mod:`mmsnap_graph.fusion.association`).

    gate_probability : the association gate (chi-square, 2 dof).
    source : the detections fused, ``"centroids"`` or ``"point_cloud"``.
    merge_body_m : a node's centroids of one frame closer than this (m) are
        one body split into clusters, merged before the association
        (:func:`~mmsnap_graph.fusion.recording.regroup.merge_body_detections`);
        None: each centroid on its own. Centroids only.
    """

    gate_probability: float = 0.999
    source: Literal["centroids", "point_cloud"] = "centroids"
    merge_body_m: float | None = CENTROID_MERGE_RADIUS_M

    def __post_init__(self) -> None:
        object.__setattr__(self, "gate_probability",
                           check_probability(self.gate_probability, "gate_probability"))
        if self.source not in ("centroids", "point_cloud"):
            raise ValidationError(f"source must be 'centroids' or 'point_cloud', got "
                                  f"{self.source!r}")
        if self.merge_body_m is not None:
            object.__setattr__(self, "merge_body_m",
                               _positive_m(self.merge_body_m, "merge_body_m"))


@dataclass(frozen=True, kw_only=True, slots=True)
class MotionCheck:
    """Each row against the constant-velocity motion of the rows of its
    neighbouring frames: refit without the nodes that disagree, or flag
    (:mod:`~mmsnap_graph.fusion.recording.motion_check`, docs/ROBUST.md)."""

    #: Frames on each side whose rows can change a row's decision.
    look_frames: ClassVar[int] = MOTION_CONTEXT_FRAMES


@dataclass(frozen=True, kw_only=True, slots=True)
class SplitCheck:
    """Flag the one-node rows of a frame that the association split
    (:mod:`~mmsnap_graph.fusion.recording.split_check`). With the motion check
    before it, the only row of a frame the motion check kept stays."""

    look_frames: ClassVar[int] = 0


def _reach(value: object) -> Mapping[str, float] | None:
    """``CoverageCheck.reach_m`` as a read-only ``{name: metres}``."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ValidationError("CoverageCheck.reach_m must be a mapping node name -> metres, got "
                              f"{type(value).__name__}")
    out = {}
    for name, reach in value.items():
        if isinstance(reach, (bool, np.bool_)) or not isinstance(
                reach, (int, float, np.integer, np.floating)) or not (math.isfinite(reach)
                                                                     and reach >= 0):
            raise ValidationError(f"CoverageCheck.reach_m[{name!r}]={reach!r} must be a finite "
                                  "number of metres >= 0")
        out[str(name)] = float(reach)
    return MappingProxyType(out)


@dataclass(frozen=True, kw_only=True, slots=True)
class CoverageCheck:
    """Flag a row that a node whose field of view covers it never sees in
    the frames around (:mod:`~mmsnap_graph.fusion.recording.coverage`: a
    multipath image). Runs on the rows the motion check left; needs it.

    reach_m : node name -> how far the node looks (m). A node left out (or
        None, the default): the farthest of its detections the driver has
        (:func:`~mmsnap_graph.fusion.recording.coverage.detection_reach_m`):
        the whole recording in memory (before the calibration's offsets), the
        whole file for the windowed driver (so that each window is judged as
        the whole recording), the detections so far for a stream.
    """

    reach_m: Mapping[str, float] | None = None
    look_frames: ClassVar[int] = MOTION_WINDOW_FRAMES

    def __post_init__(self) -> None:
        object.__setattr__(self, "reach_m", _reach(self.reach_m))

    def with_reach(self, reach_m: Mapping[str, float]) -> "CoverageCheck":
        """This check with ``reach_m`` for the nodes it does not give."""
        return CoverageCheck(reach_m={**dict(reach_m), **dict(self.reach_m or {})})


@dataclass(frozen=True, kw_only=True, slots=True)
class UnplacedCheck:
    """Flag a row seen by one node alone that no walk ties to a row seen by
    two or more nodes in the frames around
    (:mod:`~mmsnap_graph.fusion.recording.unplaced`: one radar cannot tell
    a person from a multipath image where no other radar looks). Runs after
    the coverage check, on the rows the checks before it left; its chains
    run over :attr:`look_back_frames` frames before a row and
    :attr:`look_frames` after it."""

    look_frames: ClassVar[int] = UNPLACED_LOOK_AHEAD_FRAMES
    look_back_frames: ClassVar[int] = UNPLACED_LOOK_BACK_FRAMES


@dataclass(frozen=True, kw_only=True, slots=True)
class RoomCheck:
    """The room in the reference frame (:mod:`~mmsnap_graph.fusion.recording.room`).

    bounds : the room box: a successful row outside it is flagged (None: no box).
    static_bounds : a row slower than
        :data:`~mmsnap_graph.fusion.recording.room.STILL_MPS` outside this box
        is flagged (None: none).
    in_front : the radars hang on the walls facing in: a row behind a radar is
        outside the room.
    """

    bounds: RoomBounds | None = None
    static_bounds: RoomBounds | None = None
    in_front: bool = False
    look_frames: ClassVar[int] = 0

    def __post_init__(self) -> None:
        for name in ("bounds", "static_bounds"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, RoomBounds):
                raise ValidationError(f"RoomCheck.{name} must be a RoomBounds or None, got "
                                      f"{type(value).__name__}")
        if not isinstance(self.in_front, (bool, np.bool_)):
            raise ValidationError(f"RoomCheck.in_front must be True or False, got "
                                  f"{self.in_front!r}")
        if self.bounds is None and self.static_bounds is None and not self.in_front:
            raise ValidationError("RoomCheck checks nothing: give bounds, static_bounds or "
                                  "in_front=True (or leave the check out)")


@dataclass(frozen=True, kw_only=True, slots=True)
class LearnedWalls:
    """Flag the rows beyond a wall learned from the radars' multipath images
    (:mod:`~mmsnap_graph.fusion.recording.walls`, docs/ROBUST.md).

    The walls are learned from every row the driver holds: the whole
    recording in memory, each window (with its context) of a file, the last
    ``look_back_frames`` frames of a stream, learned again every
    ``relearn_frames`` decided frames there. A stream applies the walls
    learned at a decided frame from the ``apply_after_frames``-th decided
    frame after it on (0: that frame itself), so that the learning (about
    12 us of CPU per row held: 130 ms for the 10,500 rows of 2000 frames of
    four radars and two walkers, simulated) can run beside the stream (``FrameStream(wall_executor=...)``, as ``mmsnap live`` does)
    without changing a row: ``mmsnap replay`` learns them in line and applies
    them at the same frames.
    """

    look_back_frames: int = 2000
    relearn_frames: int = 100
    apply_after_frames: int = 20
    look_frames: ClassVar[int] = WHOLE_RECORDING

    def __post_init__(self) -> None:
        object.__setattr__(self, "look_back_frames",
                           check_count(self.look_back_frames, "look_back_frames"))
        object.__setattr__(self, "relearn_frames",
                           check_count(self.relearn_frames, "relearn_frames"))
        object.__setattr__(self, "apply_after_frames",
                           check_count(self.apply_after_frames, "apply_after_frames", 0))


@dataclass(frozen=True, kw_only=True, slots=True)
class DuplicateCheck:
    """Two successful rows of a frame within one body (``body_m`` across,
    metres) are one person seen twice: the one seen by fewer nodes is flagged
    (:mod:`~mmsnap_graph.fusion.recording.room`)."""

    body_m: float = BODY_WIDTH_M
    look_frames: ClassVar[int] = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "body_m", _positive_m(self.body_m, "body_m"))


#: The check components, in the order the pipeline runs them.
CHECKS = (MotionCheck, SplitCheck, CoverageCheck, UnplacedCheck, RoomCheck, LearnedWalls,
          DuplicateCheck)
#: The checks of :data:`DEFAULT_CONFIG`: every one but the room's (which needs its size).
DEFAULT_CHECKS = (MotionCheck(), SplitCheck(), CoverageCheck(), UnplacedCheck(), LearnedWalls(),
                  DuplicateCheck())


def _checks(checks: object) -> tuple:
    if not isinstance(checks, (tuple, list)):
        raise ValidationError(f"checks must be a tuple of check components, got "
                              f"{type(checks).__name__}")
    kinds = [type(c) for c in checks]
    for c in checks:
        if type(c) not in CHECKS:
            raise ValidationError(f"checks: {c!r} is not a check component (one of "
                                  f"{', '.join(k.__name__ for k in CHECKS)})")
    if len(set(kinds)) != len(kinds):
        raise ValidationError(f"checks: each component at most once, got "
                              f"{[k.__name__ for k in kinds]}")
    ordered = tuple(sorted(checks, key=lambda c: CHECKS.index(type(c))))
    if CoverageCheck in kinds and MotionCheck not in kinds:
        raise ValidationError("checks: CoverageCheck runs on the rows the MotionCheck left; "
                              "add MotionCheck() or leave CoverageCheck out")
    room = next((c for c in checks if isinstance(c, RoomCheck)), None)
    if LearnedWalls in kinds and room is not None and room.bounds is not None:
        raise ValidationError("checks: the room bounds are the walls; give RoomCheck(bounds=...) "
                              "or LearnedWalls(), not both")
    return ordered


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionConfig:
    """How a recording is fused, in one value (module docstring).

    solve : :class:`~mmsnap_graph.fusion.options.FusionOptions`: ``solver``,
        ``covariance`` (``"laplace"`` or ``"grid"``), the LM settings.
    prior : the one-shot prior (MAP, default the paper's); None: maximum
        likelihood.
    robust : :class:`~mmsnap_graph.fusion.options.RobustOptions` (a kernel
        name is shorthand) or None (plain least squares). Default: the
        per-node residual gate. Measured on clean simulated data (networks
        A, C and a 3-node one, straight and random walks, 600 frames, 3 seeds
        each): the gate gave the same position RMSE and NEES as no robust
        fusion (to 3 digits); Huber raised the RMSE by 0.5-2 % and lowered
        the NEES by 0.05-0.15.
    association : :class:`AssociationOptions`.
    checks : the check components (:data:`CHECKS`), kept in their run order.
    """

    solve: FusionOptions = DEFAULT_OPTIONS
    prior: GaussianPrior | None = field(default_factory=GaussianPrior)
    robust: RobustOptions | None = RobustOptions(kernel="gate")
    association: AssociationOptions = AssociationOptions()
    checks: tuple = DEFAULT_CHECKS

    def __post_init__(self) -> None:
        if not isinstance(self.solve, FusionOptions):
            raise ValidationError(f"solve must be a FusionOptions, got {type(self.solve).__name__}")
        if self.prior is not None and not isinstance(self.prior, GaussianPrior):
            raise ValidationError(f"prior must be a GaussianPrior or None (maximum likelihood), "
                                  f"got {type(self.prior).__name__}")
        object.__setattr__(self, "robust", robust_options(self.robust))
        if not isinstance(self.association, AssociationOptions):
            raise ValidationError(f"association must be an AssociationOptions, got "
                                  f"{type(self.association).__name__}")
        object.__setattr__(self, "checks", _checks(self.checks))

    @property
    def mode(self) -> str:
        """``"map"`` with a prior, ``"ml"`` without."""
        return "ml" if self.prior is None else "map"

    def check(self, kind: type):
        """The component of type ``kind`` in :attr:`checks`, or None."""
        return next((c for c in self.checks if isinstance(c, kind)), None)

    def with_coverage_reach(self, reach_m: Mapping[str, float]) -> "FusionConfig":
        """This configuration with the coverage check's reach filled in from
        ``reach_m`` (the nodes it does not give); unchanged without the check."""
        cov = self.check(CoverageCheck)
        if cov is None:
            return self
        checks = tuple(cov.with_reach(reach_m) if c is cov else c for c in self.checks)
        return FusionConfig(solve=self.solve, prior=self.prior, robust=self.robust,
                            association=self.association, checks=checks)

    @property
    def look_back_frames(self) -> int:
        """Frames before a row that its checks look at: :attr:`context_frames`,
        or more for a check that looks further back (:class:`UnplacedCheck`)."""
        back = [getattr(c, "look_back_frames", 0) for c in self.checks
                if not isinstance(c, LearnedWalls)]
        return max([self.context_frames, *back])

    @property
    def context_frames(self) -> int:
        """Frames on each side of a row that its checks look at (the walls'
        whole recording not counted: they are learned from what a driver holds)."""
        return max((c.look_frames for c in self.checks), default=0)


#: The configuration of ``mmsnap fuse``, ``mmsnap batch``, ``mmsnap replay``
#: and :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording` unless told otherwise.
DEFAULT_CONFIG = FusionConfig()
#: Per-frame one-shot fusion: no robust fit, no body merge, no check that
#: looks past its frame; the split check (of the frame's own rows) stays.
PLAIN_CONFIG = FusionConfig(robust=None, association=AssociationOptions(merge_body_m=None),
                            checks=(SplitCheck(),))
