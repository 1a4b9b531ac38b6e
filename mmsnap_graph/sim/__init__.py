"""Simulation: raw-ADC cubes, bodies, trajectories and radar networks
(docs/SIMULATOR.md).

- :mod:`.networks`: configurations A, B, C (:data:`CONFIGURATIONS`), common
  areas, field-of-view and range limits;
- :mod:`.trajectories`: straight-line and random-walk torso trajectories;
- :mod:`.body`: the walking human (torso, arms, legs) as point scatterers;
- :mod:`.cube`: raw ADC cube synthesis (FMCW TDM-MIMO);
- :mod:`.simulator`: :func:`simulate_recording`, the whole recording, with
  :class:`SimulationOptions` (:mod:`.options`);
- :mod:`.real`: what real TI point clouds of people do: :mod:`.real.physics`
  (:class:`RealPhysics`, on by default; :data:`CLEAN` switches it off),
  :mod:`.real.sparse` (sparse clouds of real demos, :func:`sparse_clouds`)
  and :mod:`.real.ghosts` (centroid ghost generators for robustness tests);
- :mod:`.scenes`: small calibration scenes (tracks of one target seen by
  several nodes) for tests and benchmarks;
- :mod:`.clocks`: scenes whose nodes sample at their own clock offsets
  (:func:`timed_scene`, :func:`scene_recording`);
- :mod:`.turns`: walks with instant turns (:func:`turning_walk`);
- :mod:`.bump`: a recording in which a node is moved part-way
  (:func:`simulate_bumped_recording`).
"""

from .body import HumanBody, body_scatterers
from .networks import CONFIGURATIONS, COMMON_AREAS, Area, common_area, network_poses
from .options import CLEAN, DEFAULT_LEVELS, SimulationOptions
from .real.physics import RealPhysics
from .simulator import (
    LEVELS,
    CENTROID_NOISE,
    CubeModel,
    PointCloudModel,
    simulate_recording,
    simulate_targets,
)
from .scenes import (
    COMMON_AREA_CENTERS,
    PAPER_CONFIGURATIONS,
    SyntheticScene,
    synthetic_scene,
    target_trajectory,
)
from .trajectories import RandomWalkOptions, make_trajectory, random_walk, straight_line
from .clocks import scene_recording, timed_scene
from .turns import turning_walk
from .bump import simulate_bumped_recording
from .real.sparse import empty_frame_mask, sparse_clouds

__all__ = [
    "CONFIGURATIONS",
    "COMMON_AREAS",
    "Area",
    "common_area",
    "network_poses",
    "make_trajectory",
    "random_walk",
    "RandomWalkOptions",
    "straight_line",
    "HumanBody",
    "body_scatterers",
    "LEVELS",
    "DEFAULT_LEVELS",
    "SimulationOptions",
    "CLEAN",
    "RealPhysics",
    "CENTROID_NOISE",
    "PointCloudModel",
    "CubeModel",
    "simulate_recording",
    "simulate_targets",
    "COMMON_AREA_CENTERS",
    "PAPER_CONFIGURATIONS",
    "SyntheticScene",
    "synthetic_scene",
    "target_trajectory",
    "timed_scene",
    "scene_recording",
    "turning_walk",
    "simulate_bumped_recording",
    "sparse_clouds",
    "empty_frame_mask",
]
