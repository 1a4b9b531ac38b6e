"""The range offset at fixed node poses (mmsnap_graph/calibration/noise/depth.py)."""

import numpy as np
import pytest

from mmsnap_graph.calibration.noise.depth import MIN_FRAMES, range_offset_at_poses
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections, NodeData, Recording
from mmsnap_graph.errors import ValidationError

from _scenes import depth_scene

SIGMAS = (0.05, 0.08, 0.1)
NOISE = MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.1)


def _recording(meas, keep=None):
    nodes = {}
    for name, z in meas.items():
        frame = np.arange(z.shape[0])
        rows = slice(None) if keep is None else keep
        nodes[name] = NodeData(name=name, centroids=Detections(
            frame=frame[rows], range_m=z[rows, 0], omega_rad=z[rows, 1],
            doppler_mps=z[rows, 2]))
    return Recording(frame_period_s=0.15, nodes=nodes)


@pytest.mark.parametrize("depth", [0.0, 0.07, 0.12])
def test_the_offset_is_found_within_its_standard_error(depth):
    """Seeded Monte Carlo: 20 scenes of 200 frames; the estimates' z-scores
    against the true depth have mean within 0.5 and standard deviation
    0.6-1.5 (the reported variance is the spread's)."""
    z = []
    for seed in range(20):
        poses, _, meas = depth_scene(SIGMAS, seed=seed, n=200, depth=depth)
        est = range_offset_at_poses(_recording(meas), poses, noise=NOISE)
        assert est.identified, est.message
        z.append((est.offset_m - depth) / np.sqrt(est.variance_m2))
    assert abs(np.mean(z)) < 0.5 and 0.6 < np.std(z) < 1.5, z


def test_ghosts_do_not_move_it_and_wrong_poses_are_not_depth():
    poses, _, meas = depth_scene(SIGMAS, seed=3, n=200, depth=0.07)
    rng = np.random.default_rng(0)
    bad = rng.choice(200, 10, replace=False)
    meas["S2"][bad, 0] += rng.uniform(-3.0, 3.0, 10)       # 5 % ghost ranges
    est = range_offset_at_poses(_recording(meas), poses, noise=NOISE)
    assert est.offset_m == pytest.approx(0.07, abs=4 * np.sqrt(est.variance_m2))


def test_too_few_frames_or_nodes_is_not_identified():
    poses, _, meas = depth_scene(SIGMAS, seed=1, n=MIN_FRAMES - 1, depth=0.07)
    est = range_offset_at_poses(_recording(meas), poses, noise=NOISE)
    assert not est.identified and "frames" in est.message and np.isnan(est.offset_m)
    one = range_offset_at_poses(_recording({"S1": meas["S1"]}), poses, noise=NOISE)
    assert not one.identified and "two nodes" in one.message
    with pytest.raises(ValidationError, match="Recording"):
        range_offset_at_poses(meas, poses, noise=NOISE)
