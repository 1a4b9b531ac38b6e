"""The stream's checks frame by frame (mmsnap_graph.fusion.stream.checks)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np
import pytest

from mmsnap_graph.data.results import Status
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.fusion.recording.pipeline import check_rows
from mmsnap_graph.fusion.recording.rows import FusedRows
from mmsnap_graph.fusion.stream.checks import StreamPipeline, concat_rows
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
from mmsnap_graph.sim import SimulationOptions, simulate_recording

GHOSTS = {"S1": [0.0, 0.0, 0.0], "S2": [4.0, 0.0, np.pi / 3], "S3": [2.0, 6.0, np.pi]}


class _WholeLookBack(StreamPipeline):
    """Every check on the whole look-back held (the stream before it ran the
    checks but the placement on their context alone)."""

    def _checked(self, held, frame):
        back = self.config.look_back_frames
        held = [h for h in self._held if frame - back <= h.frame <= frame + self.delay_frames]
        n_nodes = len(self.net.node_names)
        sizes = [h.members.shape[0] for h in held]
        rows = concat_rows([h.rows for h in held], n_nodes)
        members = np.concatenate([h.members for h in held])
        z = np.concatenate([h.z for h in held])
        check_rows(rows, np.repeat([h.frame for h in held], sizes), members, z, self.net,
                   self.config, reach_m=self.reach_m, decide=np.array([frame]))
        mine = next(i for i, h in enumerate(held) if h.frame == frame)
        sl = slice(int(np.sum(sizes[:mine])), int(np.sum(sizes[:mine + 1])))
        own = FusedRows(sizes[mine], n_nodes)
        for name in FusedRows.__slots__:
            setattr(own, name, getattr(rows, name)[sl])
        return own, members[sl], z[sl]

    def _place(self, held, frame, own):
        pass


def _rows(stream, rec):
    out = []
    for _, t, det in recording_frames(rec, fill_frames=stream.tracker_config.max_misses):
        for u in stream.feed(t, det):
            out.append((u.state, u.status, u.rejected, u.message))
    return out


def test_the_checks_on_their_context_decide_as_on_the_whole_look_back():
    rec = simulate_recording(GHOSTS, "random", SimulationOptions(n_targets=2, frame_period_s=0.05,
                                                                 known_poses=True),
                             levels=("centroids",), n_frames=160, seed=3)
    poses = np.array([GHOSTS[n] for n in rec.node_names])
    fast = FrameStream(rec.node_names, poses)
    whole = FrameStream(rec.node_names, poses)
    whole._pipeline.__class__ = _WholeLookBack
    got, want = _rows(fast, rec), _rows(whole, rec)
    status = np.concatenate([s for _, s, _, _ in want])
    # The scene exercises the checks: rows flagged by the motion and placement checks.
    assert np.sum(status == Status.MOTION_INCONSISTENT) >= 5
    assert len(got) == len(want)
    for (xa, sa, ra, ma), (xb, sb, rb, mb) in zip(got, want):
        np.testing.assert_allclose(xa, xb, rtol=0, atol=1e-9)
        assert np.array_equal(sa, sb) and np.array_equal(ra, rb) and ma == mb


def test_the_checks_of_one_frame_skip_only_work_it_does_not_need(monkeypatch):
    # Deciding one frame, the motion check judges only the rows within two
    # windows of it and the one-node twins within one, and the coverage check
    # only the frame's rows: every update as when both judged the whole context.
    import mmsnap_graph.fusion.recording.coverage as coverage
    import mmsnap_graph.fusion.recording.motion_check as motion
    import mmsnap_graph.fusion.recording.pipeline as pipeline
    rec = simulate_recording(GHOSTS, "random", SimulationOptions(n_targets=3, frame_period_s=0.05,
                                                                 known_poses=True),
                             levels=("centroids",), n_frames=160, seed=5)
    poses = np.array([GHOSTS[n] for n in rec.node_names])
    got = _rows(FrameStream(rec.node_names, poses), rec)
    every = coverage.uncovered_rows
    monkeypatch.setattr(motion, "rows_near",
                        lambda frame, decide, frames: np.ones(frame.size, bool))
    monkeypatch.setattr(pipeline, "uncovered_rows",
                        lambda *a, decide=None, **k: every(*a, **k))
    want = _rows(FrameStream(rec.node_names, poses), rec)
    status = np.concatenate([s for _, s, _, _ in want])
    assert np.sum(status == Status.MOTION_INCONSISTENT) >= 5
    assert len(got) == len(want)
    for (xa, sa, ra, ma), (xb, sb, rb, mb) in zip(got, want):
        assert np.array_equal(xa, xb) and np.array_equal(sa, sb) and np.array_equal(ra, rb)
        assert ma == mb


def test_the_walls_learned_from_the_look_back_are_those_of_its_sequence(monkeypatch):
    """The stream learns the walls from the fields of its look-back that they
    read (concatenated, no FusedSequence built): every relearning's walls are
    those of the look-back's decided rows as one FusedSequence. Network C,
    one walker, walls learned."""
    import dataclasses

    import mmsnap_graph.fusion.stream.checks as checks
    from mmsnap_graph.fusion.config import LearnedWalls
    from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG

    rec = simulate_recording("C", "random", SimulationOptions(known_poses=True, n_targets=1),
                             levels=("centroids",), n_frames=400, seed=0)
    cfg = dataclasses.replace(STREAM_CONFIG, checks=tuple(
        LearnedWalls(look_back_frames=250, relearn_frames=50) if isinstance(c, LearnedWalls)
        else c for c in STREAM_CONFIG.checks))
    poses = [rec.node_poses()[n] for n in rec.node_names]
    stream = FrameStream(rec.node_names, poses, config=cfg)
    learn, learned = checks.learn_room_walls, []
    ROW_FIELDS = ("frame", "target", "label", "detection_index", "observed", "state", "covariance",
                  "laplace_covariance", "success", "status", "message", "iterations",
                  "final_cost", "degeneracy", "rejected", "time_s", "information",
                  "information_vector")

    def spy(rows):
        parts = list(stream._pipeline._history)
        whole = dataclasses.replace(parts[0], **{
            k: np.concatenate([getattr(p, k) for p in parts]) for k in ROW_FIELDS
            if getattr(parts[0], k) is not None})
        walls = learn(rows)
        assert len(rows) == len(whole) and walls == learn(whole)
        learned.append(len(walls))
        return walls

    monkeypatch.setattr(checks, "learn_room_walls", spy)
    for _, t, det in recording_frames(rec, fill_frames=stream.tracker_config.max_misses):
        stream.feed(t, det)
    assert len(learned) >= 6 and max(learned) >= 3


def _walls_scene(apply_after):
    """Network C, one walker, the walls learned every 50 decided frames from
    the last 250, applied ``apply_after`` decided frames later."""
    import dataclasses

    from mmsnap_graph.fusion.config import LearnedWalls
    from mmsnap_graph.fusion.stream.frame_stream import STREAM_CONFIG

    rec = simulate_recording("C", "random", SimulationOptions(known_poses=True, n_targets=1),
                             levels=("centroids",), n_frames=400, seed=0)
    cfg = dataclasses.replace(STREAM_CONFIG, checks=tuple(
        LearnedWalls(look_back_frames=250, relearn_frames=50, apply_after_frames=apply_after)
        if isinstance(c, LearnedWalls) else c for c in STREAM_CONFIG.checks))
    return rec, cfg, [rec.node_poses()[n] for n in rec.node_names]


def _updates(stream, rec):
    return [u for _, t, det in recording_frames(rec, fill_frames=stream.tracker_config.max_misses)
            for u in stream.feed(t, det)]


def _same_updates(a, b):
    assert len(a) == len(b)
    for u, v in zip(a, b):
        assert u.message == v.message
        for k in ("state", "covariance", "status", "rejected", "track_id", "track_state"):
            np.testing.assert_array_equal(getattr(u, k), getattr(v, k))


def test_walls_apply_the_set_number_of_decided_frames_after_their_learning(monkeypatch):
    """The walls learned at the decided frame c screen the rows from the
    decided frame c + apply_after_frames on; before, those learned earlier
    (none before the first learning). Reference: learn_room_walls of the
    look-back's rows, taken when each learning happens."""
    import mmsnap_graph.fusion.stream.checks as checks

    rec, cfg, poses = _walls_scene(7)
    stream = FrameStream(rec.node_names, poses, config=cfg)
    learn, screen = checks.learn_room_walls, checks.screen_rows
    learned, used = [], []

    def spy_learn(rows):
        learned.append((stream._pipeline._decided, learn(rows)))
        return learned[-1][1]

    def spy_screen(seq, config, walls):
        used.append(list(walls))
        return screen(seq, config, walls=walls)

    monkeypatch.setattr(checks, "learn_room_walls", spy_learn)
    monkeypatch.setattr(checks, "screen_rows", spy_screen)
    _updates(stream, rec)
    assert len(learned) >= 6 and any(w for _, w in learned)
    want, walls, pending = [], [], list(learned)
    for d in range(1, len(used) + 1):     # the decided frames, counted from 1
        while pending and pending[0][0] + 7 <= d:
            walls = pending.pop(0)[1]
        want.append(walls)
    assert used == want


def test_walls_learned_in_an_executor_give_the_rows_learned_in_line():
    """A thread pool, a worker process and a pool that fails each learning
    (its walls then learned in line): every update as in line."""
    class Failing(ThreadPoolExecutor):
        def submit(self, fn, *args, **kwargs):
            f = Future()
            f.set_exception(OSError("worker died"))
            return f

    rec, cfg, poses = _walls_scene(20)
    want = _updates(FrameStream(rec.node_names, poses, config=cfg), rec)
    assert any(np.any(u.status == Status.OUTSIDE_BOUNDS) for u in want)
    spawn = multiprocessing.get_context("spawn")
    for pool in (ThreadPoolExecutor(1), ProcessPoolExecutor(1, mp_context=spawn), Failing(1)):
        with pool:
            _same_updates(_updates(FrameStream(rec.node_names, poses, config=cfg,
                                               wall_executor=pool), rec), want)
    with pytest.raises(ValidationError, match="wall_executor"):
        FrameStream(rec.node_names, poses, config=cfg, wall_executor=object())
