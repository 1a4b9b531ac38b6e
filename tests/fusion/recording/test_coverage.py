"""The coverage check (:mod:`mmsnap_graph.fusion.recording.coverage`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _scenes import small_room_image
from _shared import POSES_BC
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.config import CoverageCheck
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.coverage import (REACH_METADATA_KEY, coverage_reach_m,
                                                    detection_reach_m, uncovered_rows)
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.sim.real.ghosts import ghost_centroids
from mmsnap_graph.sim.simulator import CENTROID_NOISE
from _fusion import config

POSES = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, np.pi / 2]])   # S1 faces +y, S2 faces -x
#: The check needs a third node: S3 far away, facing away from the room (it
#: covers none of the places below).
POSES3 = np.vstack([POSES, [-20.0, -20.0, np.pi]])


def _rows(places, kept_nodes, n_frames=7):
    """Rows of ``n_frames`` frames: one per place, still, kept by its nodes."""
    frame, state, kept = [], [], []
    for f in range(n_frames):
        for (x, y), nodes in zip(places, kept_nodes):
            frame.append(f)
            state.append([x, y, 0.0, 0.0])
            kept.append([n in nodes for n in range(3)])
    kept = np.array(kept)
    ranges = np.hypot(*(np.array(state)[:, None, :2] - POSES3[None, :, :2]).transpose(2, 0, 1))
    return np.array(frame), np.array(state), kept, ranges


def test_a_target_a_covering_node_never_sees_is_flagged():
    # A walker both nodes see; an image at (2, 4.5), which S1 covers (24 deg,
    # 4.9 m) and never sees; an image at (7, 3), behind S2 and 67 deg off
    # S1's boresight: no other node covers it.
    frame, state, kept, ranges = _rows([(1.0, 3.0), (2.0, 4.5), (7.0, 3.0)],
                                       [(0, 1), (1,), (0,)])
    flag, node = uncovered_rows(frame, state, np.ones(frame.size, bool), kept, ranges,
                                POSES3, frame_period_s=0.1, body_m=0.5)
    np.testing.assert_array_equal(flag.reshape(7, 3), [[False, True, False]] * 7)
    assert np.all(node.reshape(7, 3)[:, 1] == 0)
    # Seen by S1 in frames 1, 3 and 5 (two in every row's seven frames): a
    # target that S1 misses now and then.
    kept2 = kept.copy()
    kept2[[4, 10, 16], 0] = True
    flag, _ = uncovered_rows(frame, state, np.ones(frame.size, bool), kept2, ranges,
                             POSES3, frame_period_s=0.1, body_m=0.5)
    assert not flag.any()


def test_deciding_some_frames_judges_their_rows_alone():
    frame, state, kept, ranges = _rows([(1.0, 3.0), (2.0, 4.5), (7.0, 3.0)],
                                       [(0, 1), (1,), (0,)])
    ok = np.ones(frame.size, bool)
    full, node = uncovered_rows(frame, state, ok, kept, ranges, POSES3, frame_period_s=0.1,
                                body_m=0.5)
    part, part_node = uncovered_rows(frame, state, ok, kept, ranges, POSES3,
                                     frame_period_s=0.1, body_m=0.5, decide=np.array([2, 5]))
    judged = np.isin(frame, [2, 5])
    assert full.any() and np.array_equal(part, full & judged)
    assert np.array_equal(part_node, np.where(judged, node, -1))


def test_two_nodes_are_not_checked():
    # With two nodes the other is the only witness, and a sparse cloud's
    # misses would flag a real walker: the check needs three.
    frame, state, kept, ranges = _rows([(1.0, 3.0), (2.0, 4.5)], [(0, 1), (1,)])
    flag, node = uncovered_rows(frame, state, np.ones(frame.size, bool), kept[:, :2],
                                ranges[:, :2], POSES, frame_period_s=0.1, body_m=0.5)
    assert not flag.any() and np.all(node == -1)


def test_mirror_images_that_another_radar_covers_are_flagged_in_a_recording():
    net = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
    rec = simulate_recording(net, "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=300, seed=10)
    ghosts = ghost_centroids(rec, "mirror", 0.2, seed=110)

    def far_rows(**settings):
        fused = fuse_recording(ghosts, config(robust="gate", **settings), noise=CENTROID_NOISE, progress=False)
        err = np.hypot(*(fused.state[:, :2] - rec.truth.state[fused.frame, :2]).T)
        return fused, int(np.sum(fused.success & (err > 0.5)))

    fused, far = far_rows()
    _, far_off = far_rows(coverage_check=False)
    assert far < far_off / 2, (far, far_off)
    msg = [m for m, s in zip(fused.message, fused.status) if "covers this place" in m]
    assert msg and all(s == Status.MOTION_INCONSISTENT for m, s in zip(fused.message, fused.status)
                       if "covers this place" in m)


def _fused_small_room(recording, reach_m=None):
    from mmsnap_graph.data.noise import MeasurementNoise

    return fuse_recording(recording, config(robust="gate", coverage_reach_m=reach_m),
                          noise=MeasurementNoise(range_m=0.02, omega_rad=0.01, doppler_mps=0.05),
                          progress=False)


def test_a_node_covers_places_beyond_where_the_walkers_went():
    # Regression: the reach was the farthest of the node's own rows, 4.3 m
    # for S1 here, so S2's image 7.6 m away in S1's view was kept, a
    # confident target 4 m from the walker (a 3-radar room at 20 fps).
    rec, walker, image = small_room_image()
    fused = _fused_small_room(rec)
    at_image = np.hypot(*(fused.state[:, :2] - image[fused.frame, :2]).T) < 0.5
    at_walker = np.hypot(*(fused.state[:, :2] - walker[fused.frame, :2]).T) < 0.5
    assert at_image.sum() == 40 and at_walker.sum() == 40
    assert not fused.success[at_image].any()
    assert all("node S1 covers this place" in m for m in fused.message[at_image])
    assert fused.success[at_walker].all()
    # Told that S1 looks no farther than 5 m, the check leaves the image.
    near = _fused_small_room(rec, {"S1": 5.0})
    assert near.success[at_image].all()


def test_the_reach_is_the_farthest_detection_of_every_level():
    rec, _, _ = small_room_image()
    s1, s2 = rec.nodes["S1"], rec.nodes["S2"]
    assert detection_reach_m(s1) == 9.0                       # the static reflector
    assert detection_reach_m(s2) == pytest.approx(s2.centroids.range_m.max())
    assert detection_reach_m(dataclasses.replace(s1, centroids=None, point_cloud=None)) == 0.0


def test_the_reach_option_is_checked():
    with pytest.raises(ValidationError, match=r"reach_m\['S1'\]=-1"):
        CoverageCheck(reach_m={"S1": -1})
    with pytest.raises(ValidationError, match="reach_m must be a mapping"):
        CoverageCheck(reach_m=[5.0])
    assert dict(CoverageCheck(reach_m={"S1": 5}).reach_m) == {"S1": 5.0}
    # A reach given wins over the one a driver fills in.
    filled = CoverageCheck(reach_m={"S1": 5}).with_reach({"S1": 9.0, "S2": 7.0})
    assert dict(filled.reach_m) == {"S1": 5.0, "S2": 7.0}


def test_a_reach_the_recording_declares_is_the_one_taken(tmp_path):
    # mmsnap live --record declares each board's reach (its .cfg's maximum
    # range): fuse_recording and the windowed driver of mmsnap fuse take it
    # instead of the farthest detection (S1's static reflector at 9 m).
    from mmsnap_graph.app.chunked_fuse import fuse_file
    from mmsnap_graph.data.noise import MeasurementNoise
    from mmsnap_graph.io import read_fused, write_recording
    from mmsnap_graph.io.hdf5 import open_recording_file, recording_metadata

    rec, _, image = small_room_image()
    declared = dataclasses.replace(rec, metadata={**rec.metadata,
                                                  REACH_METADATA_KEY.format(node="S1"): 5.0})
    assert coverage_reach_m(declared)["S1"] == 5.0
    assert coverage_reach_m(rec)["S1"] == 9.0
    fused = _fused_small_room(declared)
    at_image = np.hypot(*(fused.state[:, :2] - image[fused.frame, :2]).T) < 0.5
    assert at_image.sum() == 40 and fused.success[at_image].all()
    for recording, kept in ((rec, False), (declared, True)):
        path = write_recording(tmp_path / f"{kept}.h5", recording)
        with open_recording_file(path) as h5:
            assert recording_metadata(h5).get("S1_coverage_reach_m") == (5.0 if kept else None)
        fuse_file(path, config(robust="gate"), progress=False,
                  noise=MeasurementNoise(range_m=0.02, omega_rad=0.01, doppler_mps=0.05))
        f = read_fused(path)
        here = np.hypot(*(f.state[:, :2] - image[f.frame, :2]).T) < 0.5
        assert here.sum() == 40 and (f.success[here].all() if kept else not f.success[here].any())

