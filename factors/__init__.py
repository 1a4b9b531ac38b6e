"""The physics layer: radar measurement models, the detection inverse, the
constant-velocity motion model (pure numpy) and their GTSAM factor adapters.

``factors.models`` (the measurement model in its three forms, the detection
<-> local-position inverse with its Jacobian and covariance, frame
transforms), ``factors.motion`` (constant-velocity transition and process
noise) and ``factors.robust`` (robust-kernel defaults) know numpy only;
``factors.gtsam_factors`` wraps them as GTSAM factors. Nothing here knows
about files, DSP or pipelines, nor imports :mod:`mmsnap_graph`.
"""

from .models import (
    DETECTION_MIN_COS,
    MEASUREMENT_NAMES,
    detection_covariance_global,
    detection_covariance_local,
    detection_jacobian,
    detection_to_global,
    detection_to_local,
    detection_to_local_scalar,
    global_to_local,
    local_to_global,
    measurement_model,
    measurement_model_pose,
    measurement_model_scalar,
    predict_measurements,
    residual,
    wrap_angle,
    wrap_angle_scalar,
)
from .motion import cv_process_noise, cv_process_noise_continuous, cv_transition
from .robust import ROBUST_K_DEFAULT, ROBUST_KERNELS, robust_k

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
    "wrap_angle_scalar",
    "measurement_model",
    "measurement_model_pose",
    "measurement_model_scalar",
    "predict_measurements",
    "residual",
    "DETECTION_MIN_COS",
    "detection_to_local",
    "detection_to_local_scalar",
    "detection_jacobian",
    "detection_covariance_local",
    "detection_covariance_global",
    "detection_to_global",
    "local_to_global",
    "global_to_local",
    "cv_transition",
    "cv_process_noise",
    "cv_process_noise_continuous",
    "ROBUST_KERNELS",
    "ROBUST_K_DEFAULT",
    "robust_k",
    "measurement_noise",
    "frame_measurement_factor",
    "node_measurement_factor",
    "scalar_measurement_factor",
    "pose_measurement_factor",
    "state_prior_factor",
    "constant_velocity_factor",
]
