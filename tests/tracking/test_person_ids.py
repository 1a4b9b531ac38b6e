"""Person ids of fused rows (mmsnap_graph.tracking.person_ids)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.tracking.central import CentralConfig, CentralTracker, track_fused
from mmsnap_graph.tracking.person_ids import NO_PERSON, PersonIds, assign_person_ids

P = np.diag([0.01, 0.01, 0.04, 0.04])


@pytest.fixture(scope="module")
def fused_two(two_target_recordings):
    """Configuration B, two walkers, 200 frames, 10 % missed centroids."""
    return fuse_recording(two_target_recordings["B"], progress=False)


def test_estimate_ids_name_the_track_each_estimate_went_to():
    tracker = CentralTracker(CentralConfig(max_misses=2))
    tracker.step([[0.0, 3.0, 0.0, 0.0]], [P])
    assert tracker.estimate_ids.tolist() == [0]
    # The far estimate starts track 1; the near one (given second) updates track 0.
    tracker.step([[3.0, 1.0, 0.0, 0.0], [0.02, 3.0, 0.0, 0.0]], [P, P])
    assert tracker.estimate_ids.tolist() == [1, 0]
    tracker.step(np.zeros((0, 4)), np.zeros((0, 4, 4)))
    assert tracker.estimate_ids.tolist() == []
    with pytest.raises(ValidationError):
        tracker.step([[np.nan, 3.0, 0.0, 0.0]], [P])
    assert tracker.estimate_ids.tolist() == []  # not the last good step's


def test_two_walkers_each_keep_one_id_for_most_of_their_rows(fused_two):
    """The rows of each simulated walker (its ``label``) mostly carry one id,
    and the two walkers' ids differ. Measured: 40 + 156 rows of walker 0 on
    ids 0 and 2, walker 1 on 1 and 3 (55, 138); the tracker (sigma_a 1 m/s^2)
    restarts a track at a sharp turn."""
    f = fused_two
    assert f.track_id is not None and f.track_id.shape == f.frame.shape
    main = {}
    for label in (0, 1):
        ids, counts = np.unique(f.track_id[(f.label == label) & f.success], return_counts=True)
        assert NO_PERSON not in ids
        main[label] = ids[np.argmax(counts)]
        assert counts.max() >= 0.6 * counts.sum()
    assert main[0] != main[1]


def test_ids_are_the_tracks_of_track_fused(fused_two):
    """Each successful row's id is a track that ``track_fused`` (its own loop
    over the tracker) holds at that frame, the one nearest the row."""
    f = fused_two
    tracks = track_fused(f, CentralConfig(frame_period_s=f.frame_period_s))
    alive = {(int(fr), int(t)): s for fr, t, s in zip(tracks.frame, tracks.track_id, tracks.state)}
    for k in np.flatnonzero(f.success):
        fr = int(f.frame[k])
        here = {t: s for (g, t), s in alive.items() if g == fr}
        nearest = min(here, key=lambda t: np.linalg.norm(here[t][:2] - f.state[k, :2]))
        assert int(f.track_id[k]) == nearest


def test_failed_rows_have_no_person(fused_two):
    f = dataclasses.replace(fused_two, success=fused_two.success & (fused_two.frame % 7 != 0))
    out = assign_person_ids(f)
    assert np.all(out.track_id[~out.success] == NO_PERSON)
    assert np.all(out.track_id[out.success] >= 0)


@pytest.mark.parametrize("cuts", [(50,), (1, 2, 3, 120), (13, 77, 150, 199)])
def test_windows_give_the_ids_of_the_whole_sequence(fused_two, cuts):
    """One PersonIds over consecutive windows (as ``fuse_file`` runs it) gives
    the ids of the whole sequence at once."""
    f = fused_two
    whole = assign_person_ids(f).track_id
    ids = PersonIds()
    edges = [f.frame.min(), *cuts, f.frame.max() + 1]
    parts = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        keep = (f.frame >= lo) & (f.frame < hi)
        part = dataclasses.replace(f, **{k: getattr(f, k)[keep] for k in (
            "frame", "target", "label", "detection_index", "observed", "state", "covariance",
            "laplace_covariance", "success", "status", "message", "iterations", "final_cost",
            "degeneracy", "rejected", "time_s", "information", "information_vector", "track_id")})
        parts.append(ids.assign(part).track_id)
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_rows_before_the_last_frame_tracked_are_an_error(fused_two):
    ids = PersonIds()
    ids.assign(fused_two)
    with pytest.raises(ValidationError, match="not after the last frame tracked"):
        ids.assign(fused_two)
    with pytest.raises(ValidationError, match="before start"):
        PersonIds().frame_ids(0, np.zeros((0, 4)), np.zeros((0, 4, 4)))
    with pytest.raises(ValidationError, match="config must be a CentralConfig"):
        PersonIds({"max_misses": 3})
    with pytest.raises(ValidationError, match="fused must be a FusedSequence"):
        PersonIds().assign([1, 2])


def test_a_gap_with_no_live_track_is_skipped():
    """Frames 0 and 10^9: the tracker predicts max_misses frames, then skips
    (before: a step per frame of the gap)."""
    ids = PersonIds(CentralConfig(max_misses=3))
    ids.start(frame_period_s=0.05)
    steps = []
    real_step = ids.tracker.step_ids
    ids.tracker.step_ids = lambda *a, **k: (steps.append(1), real_step(*a, **k))[1]
    assert ids.frame_ids(0, [[0.0, 3.0, 0.0, 0.0]], [P]).tolist() == [0]
    assert ids.frame_ids(10**9, [[0.0, 3.0, 0.0, 0.0]], [P]).tolist() == [1]
    assert len(steps) == 1 + 3 + 1
