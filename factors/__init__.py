"""Radar measurement models (pure numpy) and their GTSAM factor adapters.

``factors.models`` knows numpy only; ``factors.gtsam_factors`` wraps those
models as GTSAM factors. Nothing here knows about files, DSP or pipelines.
"""

from .models import (
    MEASUREMENT_NAMES,
    detection_to_global,
    detection_to_local,
    doppler_model,
    global_to_local,
    local_to_global,
    measurement_model,
    measurement_model_pose,
    omega_model,
    range_model,
    residual,
    wrap_angle,
)
from .gtsam_factors import (
    COMPONENT_INDEX,
    constant_velocity_factor,
    measurement_noise,
    node_measurement_factor,
    pose_measurement_factor,
    scalar_measurement_factor,
    state_prior_factor,
)

__all__ = [
    "MEASUREMENT_NAMES",
    "COMPONENT_INDEX",
    "wrap_angle",
    "range_model",
    "omega_model",
    "doppler_model",
    "measurement_model",
    "measurement_model_pose",
    "residual",
    "detection_to_local",
    "local_to_global",
    "global_to_local",
    "detection_to_global",
    "measurement_noise",
    "node_measurement_factor",
    "scalar_measurement_factor",
    "pose_measurement_factor",
    "state_prior_factor",
    "constant_velocity_factor",
]
