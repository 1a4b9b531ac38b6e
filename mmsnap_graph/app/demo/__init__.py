"""The end-to-end demo (``mmsnap demo``): the paper's experiments on
simulated data, calibrate on one trajectory and fuse the other.

- :mod:`.run`: the orchestrator (:class:`DemoConfig`, :func:`run_demo`,
  :func:`run_configuration`, :class:`DemoResult`);
- :mod:`.samples`: the sample recordings (find, load, simulate, truncate);
- :mod:`.chain`: each node's torso centroids and EKF track of one walker;
- :mod:`.calibration`: self-calibration of a run (closed form, joint graph);
- :mod:`.fusion`: one-shot fusion of a run, the track-level fusion benchmark
  and the central tracker;
- :mod:`.cubes`: a short raw-cube stretch through the whole signal chain.

The report and figures of a run are :mod:`mmsnap_graph.app.report` and
:mod:`mmsnap_graph.app.plots`.
"""

from .calibration import CalibrationOutcome, calibrate_run, track_alignment_rmse
from .chain import (
    DEMO_EKF_MEASUREMENT_STD,
    DEMO_EKF_SIGMA_A_MPS2,
    SingleTrack,
    centroids_near_track,
    node_chain,
    single_target_track,
)
from .cubes import CubeStretch, run_cube_stretch
from .fusion import FusionOutcome, fuse_run, global_track, track_level_fusion
from .run import DemoConfig, DemoResult, other_trajectory, run_configuration, run_demo
from .samples import (
    CONFIGURATION_NAMES,
    TRAJECTORY_NAMES,
    find_sample_data,
    load_run,
    sample_path,
    simulate_run,
    truncate_recording,
)

__all__ = [
    "CONFIGURATION_NAMES",
    "TRAJECTORY_NAMES",
    "DEMO_EKF_MEASUREMENT_STD",
    "DEMO_EKF_SIGMA_A_MPS2",
    "DemoConfig",
    "SingleTrack",
    "CalibrationOutcome",
    "FusionOutcome",
    "CubeStretch",
    "DemoResult",
    "single_target_track",
    "centroids_near_track",
    "node_chain",
    "track_alignment_rmse",
    "calibrate_run",
    "global_track",
    "track_level_fusion",
    "fuse_run",
    "sample_path",
    "find_sample_data",
    "truncate_recording",
    "simulate_run",
    "load_run",
    "run_cube_stretch",
    "run_configuration",
    "run_demo",
    "other_trajectory",
]
