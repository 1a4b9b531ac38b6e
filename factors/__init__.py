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
    measurement_model_scalar,
    omega_model,
    predict_measurements,
    range_model,
    residual,
    wrap_angle,
    wrap_angle_scalar,
)
# The GTSAM adapters load on first use, so that numpy-only layers (the radar
# signal chain, the simulator) can use the models without importing GTSAM.
_GTSAM_NAMES = (
    "COMPONENT_INDEX",
    "constant_velocity_factor",
    "measurement_noise",
    "frame_measurement_factor",
    "node_measurement_factor",
    "pose_measurement_factor",
    "scalar_measurement_factor",
    "state_prior_factor",
)


def __getattr__(name):
    if name in _GTSAM_NAMES:
        from . import gtsam_factors

        return getattr(gtsam_factors, name)
    raise AttributeError(f"module 'factors' has no attribute {name!r}")


__all__ = [
    "MEASUREMENT_NAMES",
    "COMPONENT_INDEX",
    "wrap_angle",
    "range_model",
    "omega_model",
    "doppler_model",
    "measurement_model",
    "measurement_model_pose",
    "measurement_model_scalar",
    "predict_measurements",
    "wrap_angle_scalar",
    "residual",
    "detection_to_local",
    "local_to_global",
    "global_to_local",
    "detection_to_global",
    "measurement_noise",
    "frame_measurement_factor",
    "node_measurement_factor",
    "scalar_measurement_factor",
    "pose_measurement_factor",
    "state_prior_factor",
    "constant_velocity_factor",
]
