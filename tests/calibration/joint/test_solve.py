"""The range offset (reflection depth) in the joint calibration graph, on
the simulator's near-side reflection (``RealPhysics.reflection_depth_m``:
each radar's centroid 0.05 +- 0.015 m nearer to it than the body's centre).

Measured (3-node network of tests/test_network_pose_nees.py: S1 and S3
face each other 7 m apart; one random walker, 300 frames at 150 ms; the real
physics without clutter, ghosts, split clusters or slow centroid errors, so
that only the depth breaks the point-target model; seeds 0-19; joint NEES of
the two poses, chi-square(6), band of the mean 4.58-7.61):

| joint graph | NEES | mean error of S3's y (along the S1-S3 baseline) |
|---|---|---|
| no range offset, graph marginals | 244.8 | +0.093 m |
| range offset (prior 0.10 +- 0.05 m), long-run covariance | 5.44 | -0.001 m |

The estimated offset: 0.048 m on average (true 0.05 +- 0.015 per person),
spread 0.028 m over seeds, reported 0.027 m. With the slow AR(1) centroid
errors on as well: 255.7 -> 7.81 (long-run covariance; 10.8 with the
marginals), S3's y error +0.099 -> -0.009 m.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph.calibration import calibrate_recording, pose_tangent_error
from mmsnap_graph.calibration.network import RECORDING_JOINT_OPTIONS
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.options import SimulationOptions
from mmsnap_graph.sim.physics import RealPhysics

NET = {"S1": [0.0, 0.0, 0.0], "S2": [5.0, 5.0, np.pi / 2], "S3": [0.0, 7.0, np.pi]}
DEPTH_ONLY = RealPhysics(static_centroids_per_frame=0, ghost_probability=0, split_probability=0,
                         slow_error_std_m=0.0)
WITH_OFFSET = dataclasses.replace(RECORDING_JOINT_OPTIONS, range_offset_prior_m=(0.10, 0.05))
WITHOUT = dataclasses.replace(RECORDING_JOINT_OPTIONS, covariance="model")


def _run(seed, joint):
    rec = simulate_recording(NET, "random", SimulationOptions(physics=DEPTH_ONLY),
                             levels=("centroids",), n_frames=300, seed=seed)
    cal = calibrate_recording(rec, joint=joint)
    assert cal.success and cal.method == "joint", cal.message
    e = np.concatenate([pose_tangent_error(cal.poses[n], rec.truth.node_poses[n])
                        for n in cal.joint.joint_order])
    return cal, e, float(e @ np.linalg.solve(cal.joint.joint_covariance, e))


def test_range_offset_is_estimated_reported_and_widens_the_poses():
    cal, e, _ = _run(0, WITH_OFFSET)
    j = cal.joint
    assert 0.0 < j.range_offset_m < 0.12 and 0.005 < np.sqrt(j.range_offset_variance) < 0.06
    assert "range offset" in cal.message
    for n in ("S2", "S3"):  # the offset's uncertainty is in the poses'
        assert np.all(np.linalg.eigvalsh(cal.covariances[n] - j.model_covariances[n]) > -1e-12)
    plain, e0, _ = _run(0, WITHOUT)
    assert np.isnan(plain.joint.range_offset_m)
    # S3 (facing S1): without the offset the baseline comes out short.
    assert e0[4] > 0.05 and abs(e[4]) < 0.04


@pytest.mark.slow
def test_range_offset_removes_the_depth_bias_and_the_nees_is_in_band():
    """Module doc (seeds 0-19)."""
    out = {"without": [], "with": []}
    errs = {"without": [], "with": []}
    for seed in range(20):
        for key, joint in (("without", WITHOUT), ("with", WITH_OFFSET)):
            _, e, nees = _run(seed, joint)
            out[key].append(nees)
            errs[key].append(e[4])
    lo, hi = chi2.ppf([0.025, 0.975], 6 * 20) / 20
    means = {k: float(np.mean(v)) for k, v in out.items()}
    bias = {k: float(np.mean(v)) for k, v in errs.items()}
    print(means, bias, (lo, hi))
    assert means["without"] > 10 * hi and bias["without"] > 0.07
    assert lo < means["with"] < hi
    assert abs(bias["with"]) < 0.02
