"""FusionConfig and its components (mmsnap_graph/fusion/config.py): one value
for how a recording or a stream is fused, validated when made, each check a
component that is there or not."""

from __future__ import annotations

import dataclasses

import pytest

from mmsnap_graph.data.noise import GaussianPrior
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.config import (DEFAULT_CONFIG, PLAIN_CONFIG, AssociationOptions,
                                        CoverageCheck, DuplicateCheck, FusionConfig,
                                        LearnedWalls, MotionCheck, RoomCheck, SplitCheck,
                                        UnplacedCheck)
from mmsnap_graph.fusion.options import FusionOptions, RobustOptions
from mmsnap_graph.fusion.recording.motion_check import MOTION_CONTEXT_FRAMES
from mmsnap_graph.fusion.recording.room import RoomBounds

BOX = RoomBounds(x_min=-2.0, x_max=1.6, y_min=0.0, y_max=3.6)


@pytest.mark.parametrize("make, match", [
    (lambda: AssociationOptions(source="cube"), "source must be 'centroids' or 'point_cloud'"),
    (lambda: AssociationOptions(gate_probability=1.0), r"gate_probability must be in \(0, 1\)"),
    (lambda: AssociationOptions(merge_body_m=-0.5), "merge_body_m must be a positive"),
    (lambda: RoomCheck(), "RoomCheck checks nothing"),
    (lambda: RoomCheck(bounds=(0, 1, 0, 1)), "RoomCheck.bounds must be a RoomBounds"),
    (lambda: RoomCheck(in_front="yes"), "in_front must be True or False"),
    (lambda: DuplicateCheck(body_m=0.0), "body_m must be a positive"),
    (lambda: LearnedWalls(relearn_frames=0), "relearn_frames"),
    (lambda: LearnedWalls(apply_after_frames=-1), "apply_after_frames"),
    (lambda: LearnedWalls(apply_after_frames=1.5), "apply_after_frames"),
    (lambda: FusionConfig(solve=FusionOptions(covariance="both")), "'laplace' or 'grid'"),
    (lambda: FusionConfig(solve={"solver": "gtsam"}), "solve must be a FusionOptions"),
    (lambda: FusionConfig(prior="paper"), "prior must be a GaussianPrior or None"),
    (lambda: FusionConfig(robust="ransac"), "ransac"),
    (lambda: FusionConfig(checks=(MotionCheck(), MotionCheck())), "each component at most once"),
    (lambda: FusionConfig(checks=(CoverageCheck(),)), "CoverageCheck runs on the rows the"),
    (lambda: FusionConfig(checks=(RoomCheck(bounds=BOX), LearnedWalls())), "room bounds are the"),
    (lambda: FusionConfig(checks=("motion",)), "is not a check component"),
    (lambda: FusionConfig(checks=MotionCheck()), "checks must be a tuple"),
])
def test_every_bad_setting_is_refused_when_made(make, match):
    with pytest.raises(ValidationError, match=match):
        make()


def test_checks_run_in_one_order_and_say_how_far_they_look():
    config = FusionConfig(checks=[DuplicateCheck(), SplitCheck(), MotionCheck()])
    assert [type(c) for c in config.checks] == [MotionCheck, SplitCheck, DuplicateCheck]
    assert config.context_frames == MOTION_CONTEXT_FRAMES
    assert PLAIN_CONFIG.context_frames == 0 and PLAIN_CONFIG.robust is None
    assert FusionConfig(checks=()).context_frames == 0
    assert config.check(MotionCheck) == MotionCheck() and config.check(RoomCheck) is None


def test_ml_is_no_prior_and_the_default_is_mmsnap_fuse():
    assert FusionConfig(prior=None).mode == "ml" and DEFAULT_CONFIG.mode == "map"
    paper = GaussianPrior()
    assert (DEFAULT_CONFIG.prior.mean == paper.mean).all()
    assert (DEFAULT_CONFIG.prior.sigmas == paper.sigmas).all()
    assert DEFAULT_CONFIG.robust == RobustOptions(kernel="gate")
    assert {type(c) for c in DEFAULT_CONFIG.checks} == {
        MotionCheck, SplitCheck, CoverageCheck, UnplacedCheck, LearnedWalls, DuplicateCheck}
    # The placement check looks 100 frames back, and no further ahead than the motion check.
    assert DEFAULT_CONFIG.context_frames == MOTION_CONTEXT_FRAMES == UnplacedCheck.look_frames
    assert DEFAULT_CONFIG.look_back_frames == UnplacedCheck.look_back_frames == 100
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT_CONFIG.prior = None


def test_the_coverage_reach_a_driver_fills_in_never_replaces_the_one_given():
    config = FusionConfig(checks=(MotionCheck(), CoverageCheck(reach_m={"S1": 5.0})))
    filled = config.with_coverage_reach({"S1": 9.0, "S2": 7.0})
    assert dict(filled.check(CoverageCheck).reach_m) == {"S1": 5.0, "S2": 7.0}
    assert filled.checks[0] == MotionCheck() and filled.prior == config.prior
    assert PLAIN_CONFIG.with_coverage_reach({"S1": 1.0}) is PLAIN_CONFIG
