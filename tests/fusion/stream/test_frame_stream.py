"""The streaming API (mmsnap_graph.fusion.stream.frame_stream) and ``mmsnap replay``."""

import dataclasses
import json
import re
import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mmsnap_graph.app import cli
from mmsnap_graph.data.noise import MeasurementNoise
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.data.results import Status
from mmsnap_graph.errors import MmsnapError, ValidationError
from _fusion import solved
from mmsnap_graph.fusion import FusionOptions
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.fusion.stream.frame_stream import FrameStream, recording_frames
from mmsnap_graph.io import write_recording
from mmsnap_graph.sim import SimulationOptions, simulate_recording
from mmsnap_graph.tracking.central import track_fused

from _fuzz import FUZZ_40, assert_pd
from _pose_aware import POSE_COV, pose_frames
from _shared import POSES_BC
from _fusion import config, stream_config

#: Four nodes around a 7 m square, each facing the centre.
NETWORK = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi],
           "S3": [-3.5, 3.5, -np.pi / 2], "S4": [3.5, 3.5, np.pi / 2]}


def _drop_frames(rec, lo, hi):
    """The recording without any detection in frames ``lo <= f < hi``."""
    for name in rec.node_names:
        d = rec.nodes[name].centroids
        keep = (d.frame < lo) | (d.frame >= hi)
        cent = Detections(frame=d.frame[keep], range_m=d.range_m[keep], omega_rad=d.omega_rad[keep],
                          doppler_mps=d.doppler_mps[keep],
                          target_id=None if d.target_id is None else d.target_id[keep])
        rec = rec.with_node(dataclasses.replace(rec.nodes[name], centroids=cent))
    return rec


@pytest.fixture(scope="module")
def recording():
    """Four nodes, two walking targets, 10 % missed centroids, a 30-frame gap."""
    rec = simulate_recording(NETWORK, "random",
                             SimulationOptions(physics=None, n_targets=2, known_poses=True, centroid_p_miss=0.1),
                             levels=("centroids",), n_frames=160, seed=3)
    return _drop_frames(rec, 70, 100)


def _poses(rec):
    return np.stack([rec.nodes[n].pose for n in rec.node_names])


def _stream_all(rec, solver, **kwargs):
    settings = {k: kwargs.pop(k) for k in ("prior", "gate_probability") if k in kwargs}
    stream = FrameStream(rec.node_names, _poses(rec),
                         config=stream_config(solver=solver, **settings), **kwargs)
    frames = recording_frames(rec, fill_frames=stream.tracker_config.max_misses)
    return stream, [(f, stream.push(t, d)) for f, t, d in frames]


@pytest.mark.parametrize("solver", ["gtsam", "vectorized"])
def test_stream_gives_the_fused_states_and_tracks_of_the_batch_path(recording, solver):
    fused = fuse_recording(recording, config(solver=solver), progress=False)
    tracks = track_fused(fused)
    _, updates = _stream_all(recording, solver)
    assert all(u.ok for _, u in updates)
    frame = np.concatenate([np.full(len(u), f) for f, u in updates])
    np.testing.assert_array_equal(frame, fused.frame)
    status = np.concatenate([u.status for _, u in updates])
    np.testing.assert_array_equal(status, fused.status)
    np.testing.assert_allclose(np.concatenate([u.state for _, u in updates]), fused.state,
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([u.covariance for _, u in updates]),
                               fused.covariance, rtol=1e-12, atol=1e-15)
    observed = np.concatenate([u.members >= 0 for _, u in updates])
    np.testing.assert_array_equal(observed, fused.observed)
    # The tracks of track_fused, frame by frame, across the 30-frame gap.
    t_frame = np.concatenate([np.full(u.track_id.size, f) for f, u in updates])
    t_id = np.concatenate([u.track_id for _, u in updates])
    t_state = np.concatenate([u.track_state for _, u in updates])
    t_cov = np.concatenate([u.track_covariance for _, u in updates])
    upto = t_frame <= tracks.frame.max()
    assert tracks.frame.size > 200 and np.any((tracks.frame > 60) & (tracks.frame < 100))
    np.testing.assert_array_equal(t_frame[upto], tracks.frame)
    np.testing.assert_array_equal(t_id[upto], tracks.track_id)
    np.testing.assert_allclose(t_state[upto], tracks.state, rtol=0, atol=1e-9)
    np.testing.assert_allclose(t_cov[upto], tracks.covariance, rtol=1e-9, atol=1e-12)


def test_recording_frames_fill_gaps_up_to_the_misses_and_keep_row_order(recording):
    frames = [f for f, _, _ in recording_frames(recording, fill_frames=5)]
    assert frames == sorted(frames) and len(set(frames)) == len(frames)
    # The gap 70..99 is stepped for five empty frames, then skipped.
    assert [f for f in frames if 69 <= f < 101] == [69, 70, 71, 72, 73, 74, 100]
    for f, t, dets in recording_frames(recording):
        if f == 12:
            d = recording.nodes["S3"].centroids
            np.testing.assert_array_equal(dets["S3"], d.measurements[d.frame == 12])
            assert t == pytest.approx(12 * recording.frame_period_s)
    with pytest.raises(ValidationError, match="fill_frames"):
        next(recording_frames(recording, fill_frames=-1))


BAD_FRAMES = [
    ("nan", None, {"S1": [[np.nan, 0.1, 0.0]]}, "non-finite"),
    ("inf doppler", None, {"S2": [[3.0, 0.1, np.inf]]}, "non-finite"),
    ("unknown node", None, {"S9": [[3.0, 0.1, 0.0]]}, "unknown node 'S9'"),
    ("shape", None, {"S1": [[3.0, 0.1]]}, r"shape \(K, 3\)"),
    ("negative range", None, {"S1": [[-3.0, 0.1, 0.0]]}, "negative range"),
    ("omega beyond pi", None, {"S1": [[3.0, 4.0, 0.0]]}, "omega"),
    ("not numbers", None, {"S1": [["a", "b", "c"]]}, "not numbers"),
    ("time nan", np.nan, {}, "not finite"),
    ("time string", "soon", {}, "not a number"),
    ("time backwards", "back", {}, "not after"),
    ("wrong node count", None, [np.zeros((0, 3))], "2 nodes"),
]


@pytest.mark.parametrize("label, time_s, detections, message", BAD_FRAMES, ids=[b[0] for b in BAD_FRAMES])
def test_a_bad_frame_is_flagged_and_changes_nothing(label, time_s, detections, message):
    rec = simulate_recording("C", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=30, seed=1)
    frames = list(recording_frames(rec))
    clean = FrameStream(rec.node_names, _poses(rec))
    dirty = FrameStream(rec.node_names, _poses(rec))
    ref, out = [], []
    for k, (_, t, d) in enumerate(frames):
        if k == 10:
            # A valid time between the frames unless the time stamp is what is bad.
            stamp = {None: t - 0.05, "back": t - 5.0}.get(time_s, time_s)
            bad = dirty.push(stamp, detections)
            assert not bad.ok and len(bad) == 0
            assert bad.message and re.search(message, bad.message), bad.message
            # The tracks are reported as they were, the stream goes on.
            np.testing.assert_array_equal(bad.track_id, out[-1].track_id)
        ref.append(clean.push(t, d))
        out.append(dirty.push(t, d))
    assert dirty.bad_frames == 1 and dirty.frames == clean.frames + 1
    for a, b in zip(ref, out):
        assert a.ok and b.ok
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.track_state, b.track_state)


def test_a_numerically_degenerate_frame_does_not_stop_the_stream():
    """Range 0 at omega 0 and a tiny range (issue 13): flagged or fused, never raised."""
    rec = simulate_recording("C", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=20, seed=2)
    stream = FrameStream(rec.node_names, _poses(rec))
    frames = list(recording_frames(rec))
    for _, t, d in frames[:5]:
        assert stream.push(t, d).ok
    for k, bad in enumerate(([[0.0, 0.0, 0.0]], [[1e-300, np.pi, 0.0]])):
        u = stream.push(frames[5 + k][1], {"S1": bad, "S2": [[0.0, 0.0, 0.0]]})
        assert u.ok is False or np.all(np.isfinite(u.state[u.success]))
    for _, t, d in frames[7:]:
        u = stream.push(t, d)
        assert u.ok and u.success.all()
    assert stream.n_tracks >= 1


def test_stream_validates_its_settings():
    poses = np.zeros((2, 3))
    with pytest.raises(ValidationError, match="node_poses"):
        FrameStream(["S1", "S2"], np.zeros((3, 3)))
    with pytest.raises(ValidationError, match="node_names"):
        FrameStream(["S1", "S1"], poses)
    with pytest.raises(ValidationError, match="solver"):
        FrameStream(["S1", "S2"], poses, config=stream_config(solver="scipy"))
    with pytest.raises(ValidationError, match="gate_probability"):
        FrameStream(["S1", "S2"], poses, config=stream_config(gate_probability=1.5))
    with pytest.raises(ValidationError, match="noise"):
        FrameStream(["S1", "S2"], poses, noise="paper")
    with pytest.raises(ValidationError, match="tracker"):
        FrameStream(["S1", "S2"], poses, tracker={"max_misses": 3})


def test_ml_stream_flags_single_node_groups_like_the_batch_path():
    rec = simulate_recording("C", "random",
                             SimulationOptions(physics=None, known_poses=True, centroid_p_miss=0.3),
                             levels=("centroids",), n_frames=60, seed=4)
    fused = fuse_recording(rec, config(mode="ml", solver="gtsam"), progress=False)
    _, updates = _stream_all(rec, "gtsam", prior=None)
    status = np.concatenate([u.status for _, u in updates])
    np.testing.assert_array_equal(status, fused.status)
    assert np.any(status != Status.OK) and np.any(status == Status.OK)


@pytest.mark.slow
def test_state_stays_bounded_over_10000_frames():
    """10,000 frames: bursts of a target (a track starts), empty frames (it
    ends), a bad frame in each burst; tracks end, memory does not grow."""
    rec = simulate_recording("C", "random", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=300, seed=5)
    frames = [d for _, _, d in recording_frames(rec)]
    stream = FrameStream(rec.node_names, _poses(rec), config=stream_config())
    n_tracks, ids = [], set()
    tracemalloc.start()
    try:
        for k in range(10_000):
            burst, phase = divmod(k, 20)
            if phase < 3:
                detections = frames[(3 * burst + phase) % len(frames)]
            elif phase == 10:
                detections = {"S1": [[np.nan, 0.0, 0.0]]}
            else:
                detections = {}
            u = stream.push(k * rec.frame_period_s, detections)
            assert u.ok == (phase != 10)
            n_tracks.append(u.track_id.size)
            ids.update(u.track_id.tolist())
            if k == 1999:
                start_mem = tracemalloc.get_traced_memory()[0]
        end_mem = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert stream.frames == 10_000 and stream.bad_frames == 500
    assert max(n_tracks) <= 2 and stream.n_tracks == 0
    assert len(ids) >= 450  # a track per burst, each ended
    assert end_mem - start_mem < 256 * 1024, (start_mem, end_mem)


# ---------------------------------------------------------------------------
# mmsnap replay


@pytest.fixture
def replay_cli():
    assert "replay" in cli.COMMANDS  # registered with the other sub-commands
    return cli.main


@pytest.fixture(scope="module")
def small_file(tmp_path_factory):
    rec = simulate_recording("C", "straight", SimulationOptions(physics=None, known_poses=True),
                             levels=("centroids",), n_frames=12, seed=6)
    path = tmp_path_factory.mktemp("replay") / "rec.h5"
    write_recording(path, rec)
    return path


def test_replay_prints_a_line_per_frame_and_writes_nothing(replay_cli, small_file, capsys):
    before = sorted(small_file.parent.iterdir())
    mtime = small_file.stat().st_mtime_ns
    assert replay_cli(["replay", str(small_file)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 13 and lines[0].startswith("frame      0")
    assert lines[-1].startswith("replayed 12 frames: 12 fused targets (12 ok")
    assert "track 0:" in lines[5]
    assert sorted(small_file.parent.iterdir()) == before and small_file.stat().st_mtime_ns == mtime


def test_replay_summary_output_and_realtime(replay_cli, small_file, capsys, tmp_path):
    out = tmp_path / "frames.jsonl"
    t0 = time.monotonic()
    assert replay_cli(["replay", str(small_file), "--summary", "--speed", "10", "-o", str(out)]) == 0
    elapsed = time.monotonic() - t0
    assert elapsed >= 11 * 0.150 / 10 * 0.95  # 12 frames paced at 10x the recorded rate
    text = capsys.readouterr().out.strip().splitlines()
    assert len(text) == 2 and text[0].startswith("replayed 12 frames") and "median" in text[0]
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["frame"] for r in rows] == list(range(12))
    assert all(r["ok"] and len(r["state"]) == 1 and len(r["covariance"][0]) == 4 for r in rows)


def test_replay_usage_errors(replay_cli, small_file, capsys):
    assert replay_cli(["replay", str(small_file), "--speed", "0"]) == 2
    assert "--speed" in capsys.readouterr().err
    assert replay_cli(["replay", str(small_file), "-o", str(small_file.parent)]) == 2
    assert "is a directory" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        replay_cli(["replay", str(small_file), "--solver", "scipy"])
    assert exc.value.code == 2


def test_frame_stream_passes_pose_covariances(recording_bc_known_poses):
    stream = FrameStream(recording_bc_known_poses.node_names, POSES_BC, config=stream_config(solver="vectorized"), pose_covariances={"S2": POSE_COV[1], "S3": POSE_COV[2]})
    _, z = pose_frames(np.random.default_rng(10), 1)
    update = stream.push(0.1, [z[0, n][None] for n in range(3)])
    ref = solved(POSES_BC, z, solver="vectorized", pose_covariances=POSE_COV)
    np.testing.assert_allclose(update.covariance[0], ref.covariance[0], rtol=1e-12)


EDGE = st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, np.nan, np.inf, -np.inf,
                        np.pi, -np.pi, 1e154, 5e-324])


REAL = st.floats(-20, 20, allow_nan=False)


VALUE = st.one_of(REAL, REAL, REAL, EDGE)


POSES = np.array([[0.0, 0.0, 0.0], [0.0, 7.0, np.pi], [3.5, 3.5, np.pi / 2]])


NAMES = ["S1", "S2", "S3"]


def detections(draw, n_nodes):
    """Per-node (K, 3) rows: mostly radar-like, sometimes edge values."""
    out = {}
    for name in NAMES[:n_nodes]:
        k = draw(st.integers(0, 3))
        if draw(st.booleans()):                           # plausible rows
            rows = [[draw(st.floats(0.5, 9)), draw(st.floats(-3, 3)), draw(st.floats(-2, 2))]
                    for _ in range(k)]
        else:
            rows = [[draw(VALUE) for _ in range(3)] for _ in range(k)]
        out[name] = np.array(rows, dtype=float).reshape(k, 3)
    return out


@st.composite
def stream_runs(draw):
    n_nodes = draw(st.integers(2, 3))
    frames = []
    t = 0.0
    for _ in range(draw(st.integers(1, 5))):
        t = t + draw(st.sampled_from([0.15, 0.15, 0.05, 0.0, -0.1, np.nan, 1e5]))
        frames.append((t, detections(draw, n_nodes)))
    sigma = draw(st.sampled_from([None, 1e-300, 1e-8, 1e8]))
    return n_nodes, frames, sigma, draw(st.sampled_from(["gtsam", "vectorized"]))


@FUZZ_40
@given(stream_runs())
def test_frame_stream_never_raises_and_ok_groups_are_sound(run):
    n_nodes, frames, sigma, solver = run
    noise = None if sigma is None else MeasurementNoise(range_m=sigma, omega_rad=sigma,
                                                        doppler_mps=sigma)
    try:
        stream = FrameStream(NAMES[:n_nodes], POSES[:n_nodes],
                             config=stream_config(solver=solver),
                             **({} if noise is None else {"noise": noise}))
    except MmsnapError:
        return
    for t, dets in frames:
        update = stream.push(t, dets)                     # never raises
        for g in np.flatnonzero(update.success):
            assert np.all(np.isfinite(update.state[g])), update.state[g]
            assert_pd(update.covariance[g])
        assert np.all(np.isfinite(update.track_state))
        for cov in update.track_covariance:
            assert_pd(cov)


# Found by test_frame_stream_never_raises_and_ok_groups_are_sound with 400
# random examples: a central-tracker track outlived any gap between two pushes
# (deletion counted pushes, not seconds) and its predicted covariance lost
# positive definiteness (smallest eigenvalue 0.0 after 1e6 s, -4.5e15 after
# 1e8 s, -2.9e31 after 1e12 s, with ok=True). Failed before the fix.
@pytest.mark.parametrize("gap_s", [1e6, 1e8, 1e12])
def test_live_tracks_keep_a_positive_definite_covariance_after_a_long_gap(gap_s):
    stream = FrameStream(NAMES[:2], POSES[:2])
    stream.push(0.15, {"S2": [[1.0, 0.0, 0.0]]})
    stream.push(0.30, {})
    update = stream.push(0.30 + gap_s, {})
    for cov in update.track_covariance:
        assert_pd(cov)


@pytest.mark.parametrize("bad_time", ["1e308", "ms"])
def test_a_far_future_stamp_rejects_its_frame_only(recording, bad_time):
    stream = FrameStream(recording.node_names, _poses(recording), config=stream_config(solver="vectorized"))
    frames = list(recording_frames(recording))[:40]
    updates = []
    for i, (_, t, d) in enumerate(frames):
        if i == 20:  # one stamp far ahead: 1e308 s, or milliseconds given as seconds
            u = stream.push(1e308 if bad_time == "1e308" else t * 1e3 + 1e5, d)
            assert not u.ok and "jumps" in u.message and "frame rejected" in u.message
            continue
        updates.append(stream.push(t, d))
    assert all(u.ok for u in updates), [u.message for u in updates if not u.ok][:3]
    assert stream.bad_frames == 1


def test_detections_beyond_the_cap_are_dropped_and_counted_and_push_stays_fast():
    # The grouping grows as K^2.4 with K detections per node (1,000 per node
    # took 1.5 s, 5,000 took 74 s); rows beyond max_detections_per_node are
    # left out of the frame, counted and named.
    from mmsnap_graph.fusion.stream.frame_stream import MAX_DETECTIONS_PER_NODE
    rng = np.random.default_rng(5)

    def rows(k):
        return np.column_stack([rng.uniform(1, 6, k), rng.uniform(-2, 2, k), rng.normal(0, 1, k)])

    stream = FrameStream(NAMES[:2], POSES[:2])
    start = time.perf_counter()
    update = stream.push(0.15, {"S1": rows(5000), "S2": rows(10)})
    assert time.perf_counter() - start < 3.0
    assert update.ok and update.dropped_detections == 5000 - MAX_DETECTIONS_PER_NODE
    assert "max_detections_per_node=256" in update.message and "S1 (5000)" in update.message
    assert update.members[:, 0].max() < MAX_DETECTIONS_PER_NODE
    small = FrameStream(NAMES[:2], POSES[:2], max_detections_per_node=2)
    u = small.push(0.15, {"S1": rows(3), "S2": rows(2)})
    assert u.dropped_detections == 1 and u.members[:, 0].max() <= 1
    assert small.push(0.30, {"S1": rows(2)}).dropped_detections == 0
    for bad in (0, 5000, 2.5, "x"):
        with pytest.raises(ValidationError, match="max_detections_per_node"):
            FrameStream(NAMES[:2], POSES[:2], max_detections_per_node=bad)


@pytest.mark.parametrize("restart_at", [0.0, 50.0])
def test_a_clock_restart_does_not_lock_the_stream(recording, restart_at):
    # A source's time goes back (a radar rebooted): every later frame was
    # "not after the previous frame's" stamp, for good. After
    # CLOCK_RESTART_FRAMES rejected frames whose stamps advance, the stream
    # starts over.
    from mmsnap_graph.fusion.stream.frame_stream import CLOCK_RESTART_FRAMES
    stream = FrameStream(recording.node_names, _poses(recording), config=stream_config(solver="vectorized"))
    frames = list(recording_frames(recording))[:60]
    for _, t, d in frames[:30]:
        assert stream.push(t + 100.0, d).ok
    later = [stream.push(restart_at + t, d) for _, t, d in frames[30:]]
    rejected = [u for u in later if not u.ok]
    assert len(rejected) == CLOCK_RESTART_FRAMES - 1
    assert all("not after" in u.message for u in rejected)
    assert "clock restarted" in later[CLOCK_RESTART_FRAMES - 1].message
    assert all(u.ok for u in later[CLOCK_RESTART_FRAMES - 1:])
    assert stream.clock_restarts == 1 and stream.bad_frames == CLOCK_RESTART_FRAMES - 1
    assert later[-1].track_id.size > 0


def test_scattered_bad_stamps_do_not_restart_the_clock(recording):
    stream = FrameStream(recording.node_names, _poses(recording), config=stream_config(solver="vectorized"))
    frames = list(recording_frames(recording))[:40]
    for i, (_, t, d) in enumerate(frames):
        bad = i in (10, 20, 30)  # one stale stamp at a time, good frames between
        u = stream.push(0.01 if bad else t + 1.0, d)
        assert u.ok is not bad
    assert stream.clock_restarts == 0 and stream.bad_frames == 3


def test_no_sequence_of_stamps_locks_the_stream():
    # Seeded mutations of the time stamps (back, far ahead, NaN, repeats):
    # whatever came before, a source that then sends advancing stamps is
    # fused again within CLOCK_RESTART_FRAMES frames.
    from mmsnap_graph.fusion.stream.frame_stream import CLOCK_RESTART_FRAMES
    rng = np.random.default_rng(21)
    det = {"S1": [[3.0, 0.2, 0.1]], "S2": [[4.0, -0.3, 0.2]]}
    for _ in range(40):
        stream = FrameStream(NAMES[:2], POSES[:2])
        t = 0.0
        for _ in range(int(rng.integers(1, 12))):
            t = float(rng.choice([t + 0.15, t - 50.0, t + 1e6, np.nan, t, -1e300, 1e308]))
            stream.push(t, det)
        start = float(rng.uniform(-1e4, 1e4))
        oks = [stream.push(start + 0.15 * k, det).ok for k in range(CLOCK_RESTART_FRAMES + 3)]
        assert all(oks[CLOCK_RESTART_FRAMES - 1:]), oks


def test_set_poses_fuses_the_next_frames_with_the_new_poses_and_keeps_the_tracks(recording):
    truth = _poses(recording)
    wrong = truth.copy()
    wrong[1] += [0.3, -0.2, 0.05]
    frames = recording_frames(recording, fill_frames=5)
    right = FrameStream(recording.node_names, truth, config=stream_config(solver="vectorized"))
    moved = FrameStream(recording.node_names, wrong, config=stream_config(solver="vectorized"))
    switch, differed = 40, 0
    for k, (f, t, d) in enumerate(frames):
        if k == switch:
            ids = set(u.track_id.tolist())
            assert ids and moved.n_tracks
            moved.set_poses(truth)
            np.testing.assert_array_equal(moved.node_poses, truth)
        a, u = right.push(t, d), moved.push(t, d)
        if k < switch and len(a.state) and len(u.state) == len(a.state):
            differed += not np.allclose(u.state, a.state, atol=1e-3)
        if k == switch:    # the tracks go on: no id starts over
            assert ids & set(u.track_id.tolist())
        if switch <= k < switch + 20:
            np.testing.assert_allclose(u.state, a.state, rtol=0, atol=1e-9)
    assert differed > 10
    with pytest.raises(ValidationError, match="node_poses"):
        moved.set_poses(truth[:2])
