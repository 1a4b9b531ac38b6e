"""Issue 11's outlier target, measured where the issue measured it: a whole
3-node recording fused by ``fuse_recording`` / ``mmsnap fuse`` with 10% and
20% of the centroids replaced by ghosts (docs/ROBUST.md).

Target: position RMSE at most 1.3x / 1.6x the clean run, a ghost target in
at most 2% of the frames, the NEES of the rows kept inside the 95%
chi-square band. The per-frame gate alone cannot (``tests/fusion/test_robust.py``:
one frame's mirror ambiguity); the motion check
(:mod:`mmsnap_graph.fusion.recording.motion_check`, on by default with ``robust``)
uses the neighbouring frames.

The ghost model is ``tests/fusion/test_robust.py``'s: each centroid is replaced with
probability ``p`` by one uniform in the field of view (range 0.5-10 m,
azimuth +-60 degrees, Doppler +-3 m/s), independently per node and frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from mmsnap_graph.evaluation import chi2_mean_interval, nees

from _shared import POSES_BC
from mmsnap_graph.fusion import FusionOptions
from mmsnap_graph.app.chunked_fuse import fuse_file
from mmsnap_graph.app.cli import main
from mmsnap_graph.data.results import Status
from mmsnap_graph.fusion.recording.sequence import fuse_recording
from mmsnap_graph.io import read_fused, write_recording
from mmsnap_graph.sim import simulate_recording
from mmsnap_graph.sim.simulator import CENTROID_NOISE
from mmsnap_graph.sim import SimulationOptions
from _fusion import config

NETWORK = {"S1": POSES_BC[0], "S2": POSES_BC[1], "S3": POSES_BC[2]}
#: A fused row further than this from the truth is a ghost target (the clean
#: position RMSE is 0.05 m: 10 sigma).
GHOST_ERROR_M = 0.5


def recording(seed: int, n_frames: int = 600):
    return simulate_recording(NETWORK, "random",
                              SimulationOptions(physics=None, known_poses=True),
                              levels=("centroids",), n_frames=n_frames, seed=seed)


def with_ghosts(rec, p_ghost: float, seed: int):
    """``rec`` with each centroid replaced with probability ``p_ghost`` by a
    ghost (module docstring); a ghost's ``target_id`` is -1."""
    rng = np.random.default_rng(seed)
    nodes = {}
    for name, node in rec.nodes.items():
        c = node.centroids
        g = rng.random(len(c)) < p_ghost
        k = int(g.sum())
        r, w, v = c.range_m.copy(), c.omega_rad.copy(), c.doppler_mps.copy()
        r[g] = rng.uniform(0.5, 10.0, k)
        w[g] = np.pi * np.sin(rng.uniform(-np.pi / 3, np.pi / 3, k))
        v[g] = rng.uniform(-3.0, 3.0, k)
        tid = np.where(g, -1, c.target_id)
        nodes[name] = dataclasses.replace(node, centroids=dataclasses.replace(
            c, range_m=r, omega_rad=w, doppler_mps=v, target_id=tid))
    return dataclasses.replace(rec, nodes=nodes)


@dataclasses.dataclass
class Tally:
    """Sums over runs: squared position errors and NEES of the rows kept,
    frames with a ghost target, frames without a fused target."""

    se: float = 0.0
    nees: list = dataclasses.field(default_factory=list)
    ghost_frames: int = 0
    empty_frames: int = 0
    frames: int = 0

    def add(self, fused, rec) -> None:
        truth = np.full((rec.truth.frame.max() + 1, 4), np.nan)
        truth[rec.truth.frame] = rec.truth.state
        ok = fused.success
        err = fused.state - truth[fused.frame]
        pos = np.hypot(err[:, 0], err[:, 1])
        self.se += float(np.sum(pos[ok] ** 2))
        self.nees.append(nees(err[ok], fused.covariance[ok]))
        frames, at = np.unique(fused.frame, return_inverse=True)
        n_ok = np.bincount(at, weights=ok, minlength=frames.size)
        far = np.bincount(at, weights=ok & (pos > GHOST_ERROR_M), minlength=frames.size)
        self.ghost_frames += int(np.sum((far > 0) | (n_ok > 1)))
        self.empty_frames += int(np.sum(n_ok == 0))
        self.frames += frames.size

    @property
    def rmse(self) -> float:
        return float(np.sqrt(self.se / sum(n.size for n in self.nees)))

    def nees_and_band(self) -> tuple[float, float, float]:
        n = np.concatenate(self.nees)
        lo, hi = chi2_mean_interval(4, n.size, 0.95)
        return float(n.mean()), float(lo), float(hi)


def run_monte_carlo(motion_check: bool | None = None) -> dict:
    """Six seeded 600-frame recordings, clean and with 10% / 20% ghosts,
    fused with the simulator's centroid sigmas and ``robust="gate"``
    (the motion check on by default): a :class:`Tally` per ghost fraction."""
    tallies = {p: Tally() for p in (0.0, 0.1, 0.2)}
    for seed in range(10, 16):
        rec = recording(seed)
        for p, tally in tallies.items():
            data = with_ghosts(rec, p, seed + 100) if p else rec
            tally.add(fuse_recording(data, config(robust="gate", motion_check=motion_check), noise=CENTROID_NOISE, progress=False), rec)
    return tallies


@pytest.fixture(scope="module")
def monte_carlo():
    return run_monte_carlo()


@pytest.mark.slow
@pytest.mark.parametrize("p_ghost, factor", [(0.1, 1.3), (0.2, 1.6)])
def test_ghost_recording_meets_the_issue_11_target(monte_carlo, p_ghost, factor):
    """Measured (seeds 10-15, 3600 frames each): clean 0.0529 m; 10% ghosts
    0.0596 m (1.13x), NEES 4.00, ghost targets in 0.03% of frames (1, as
    clean), 0.06% of frames without a target; 20% ghosts 0.0672 m (1.27x),
    NEES 4.04, 0.03%, 0.53%; band (3.91, 4.09)."""
    clean, tally = monte_carlo[0.0], monte_carlo[p_ghost]
    assert tally.rmse <= factor * clean.rmse, (tally.rmse, clean.rmse)
    assert tally.ghost_frames <= 0.02 * tally.frames, tally.ghost_frames
    nees, lo, hi = tally.nees_and_band()
    assert lo < nees < hi, (nees, lo, hi)
    # Flagging is not how the target is met: at most 2% of frames are left
    # without a fused target.
    assert tally.empty_frames <= 0.02 * tally.frames, tally.empty_frames


@pytest.mark.slow
def test_clean_recording_is_not_made_worse(monte_carlo):
    """Clean data: the motion check makes nothing worse (RMSE at most 2%
    above plain fusion's, NEES in band, every frame keeps its target).
    Measured: 0.0529 m against 0.0550 m plain (the one-node rows that count
    the target twice, where the association split a frame, are flagged:
    frames with a second target 10 -> 1 of 3600). Plain fusion now flags
    those rows too (fusion.recording.split_check: 0 of 3600), so the bound on frames
    with a second target is absolute: at most 0.1% (the issue allows 2%)."""
    tally = Tally()
    for seed in range(10, 16):
        rec = recording(seed)
        tally.add(fuse_recording(rec, config(), noise=CENTROID_NOISE, progress=False), rec)
    clean = monte_carlo[0.0]
    assert clean.rmse <= 1.02 * tally.rmse, (clean.rmse, tally.rmse)
    nees, lo, hi = clean.nees_and_band()
    assert lo < nees < hi, (nees, lo, hi)
    assert clean.empty_frames == 0 and clean.ghost_frames <= 0.001 * clean.frames


def test_ghost_detections_are_rejected_or_flagged():
    """Every ghost centroid ends in a flagged row or is ``rejected`` in its
    row, but a few (1%: a ghost near the target); a flagged row says why."""
    rec = with_ghosts(recording(3, n_frames=300), 0.2, 7)
    fused = fuse_recording(rec, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    assert fused.robust == "gate"
    ghosts = used = 0
    for n, name in enumerate(rec.node_names):
        tid = rec.nodes[name].centroids.target_id
        seen = fused.observed[:, n]
        is_ghost = tid[fused.detection_index[seen, n]] < 0
        kept = fused.success[seen] & ~fused.rejected[seen, n]
        ghosts += int(is_ghost.sum())
        used += int(np.sum(is_ghost & kept))
    assert ghosts > 100 and used <= 0.01 * ghosts, (used, ghosts)
    flagged = np.isin(fused.status, [Status.RESIDUAL_TEST_FAILED, Status.MOTION_INCONSISTENT])
    assert flagged.any() and (fused.status == Status.MOTION_INCONSISTENT).any()
    assert all("motion check" in m or "chi-square" in m for m in fused.message[flagged])
    motion = fused.status == Status.MOTION_INCONSISTENT
    assert all(m.startswith("motion check") for m in fused.message[motion])
    assert np.all(np.isnan(fused.covariance[~fused.success]))


def test_a_frame_no_neighbour_explains_is_flagged_not_fused():
    """A lone frame of two ghosts that agree with each other, between clean
    frames elsewhere: never a confident target."""
    rec = recording(5, n_frames=60)
    base = fuse_recording(rec, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    # Frame 30: every node's centroid moved 3 m away (a consistent ghost
    # target for one frame).
    nodes = {}
    for name, node in rec.nodes.items():
        c = node.centroids
        r = np.where(c.frame == 30, c.range_m + 3.0, c.range_m)
        nodes[name] = dataclasses.replace(node, centroids=dataclasses.replace(c, range_m=r))
    moved = fuse_recording(dataclasses.replace(rec, nodes=nodes), config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    at = moved.frame == 30
    assert at.any() and not moved.success[at].any()
    assert "motion check" in moved.message[at][0]
    np.testing.assert_array_equal(moved.success[~at], base.success[base.frame != 30])
    plain = fuse_recording(dataclasses.replace(rec, nodes=nodes), config(robust="gate", motion_check=False), noise=CENTROID_NOISE, progress=False)
    # One frame alone cannot tell: without the motion check the frame is at
    # best flagged as split by the association (fusion.recording.split_check).
    assert not any("motion check" in m for m in plain.message[plain.frame == 30])


def test_batch_and_gtsam_agree_with_the_motion_check():
    rec = with_ghosts(recording(4, n_frames=80), 0.2, 9)
    fb = fuse_recording(rec, config(robust="gate", solver="vectorized"), noise=CENTROID_NOISE, progress=False)
    fg = fuse_recording(rec, config(robust="gate", solver="gtsam"), noise=CENTROID_NOISE, progress=False)
    np.testing.assert_array_equal(fb.status, fg.status)
    np.testing.assert_array_equal(fb.rejected, fg.rejected)
    ok = fb.success
    np.testing.assert_allclose(fb.state[ok], fg.state[ok], atol=1e-6)
    assert any("motion check" in m for m in fb.message)


@pytest.mark.parametrize("window", [4, 13, 100_000])
def test_fuse_file_windows_give_fuse_recordings_rows(tmp_path, window):
    """The motion check looks at neighbouring frames: each window of
    ``mmsnap fuse`` is fused with context frames around it and gives the
    rows of the whole recording."""
    rec = with_ghosts(recording(6, n_frames=120), 0.2, 11)
    path = write_recording(tmp_path / "ghosts.h5", rec)
    ref = fuse_recording(rec, config(robust="gate"), noise=CENTROID_NOISE, progress=False)
    out = tmp_path / "out.h5"
    fuse_file(path, config(robust="gate", walls=True), output=out, window_frames=window, progress=False, noise=CENTROID_NOISE)
    got = read_fused(out)
    for k in ("frame", "target", "observed", "success", "status", "rejected"):
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
    np.testing.assert_allclose(got.state, ref.state, rtol=0, atol=1e-7)
    assert list(got.message) == list(ref.message)


def test_mmsnap_fuse_on_a_ghost_recording(tmp_path, capsys):
    """Through the CLI as the issue measured it (its defaults: robust gate,
    motion check), with the data's sigmas: 10% ghosts against the clean
    file, one 600-frame recording. Measured: 1.08x, no ghost target."""
    rec = recording(1)
    clean_path = write_recording(tmp_path / "clean.h5", rec)
    ghost_path = write_recording(tmp_path / "ghost.h5", with_ghosts(rec, 0.1, 101))
    sigmas = [str(s) for s in CENTROID_NOISE.sigmas]
    tallies = []
    for path in (clean_path, ghost_path):
        assert main(["fuse", str(path), "--sigmas", *sigmas, "--no-progress"]) == 0
        assert "motion check" in capsys.readouterr().out
        tally = Tally()
        tally.add(read_fused(path), rec)
        tallies.append(tally)
    clean, ghost = tallies
    assert ghost.rmse <= 1.3 * clean.rmse, (ghost.rmse, clean.rmse)
    assert ghost.ghost_frames <= 0.02 * ghost.frames
    nees, lo, hi = ghost.nees_and_band()
    assert lo < nees < hi, (nees, lo, hi)
    assert main(["fuse", str(ghost_path), "--sigmas", *sigmas, "--no-progress",
                 "--no-motion-check"]) == 0
    off = Tally()
    off.add(read_fused(ghost_path), rec)
    # What the check removes: the mirror solutions of rows with a ghost range
    # (measured 0.151 m against 0.056 m). The one-node ghost rows of split
    # frames are flagged without it too (fusion.recording.split_check: 1 ghost frame).
    assert off.rmse > 2.0 * ghost.rmse, (off.rmse, ghost.rmse)


def _print_figures(motion_check: bool) -> None:
    """The figures the tests assert, printed (``python
    tests/fusion/recording/test_motion_check.py``; ``--no-motion-check``: the gate alone)."""
    tallies = run_monte_carlo(motion_check)
    clean = tallies[0.0]
    for p, t in tallies.items():
        nees, lo, hi = t.nees_and_band()
        print(f"ghosts {p:.0%}: position RMSE {t.rmse:.4f} m ({t.rmse / clean.rmse:.2f}x clean), "
              f"NEES {nees:.2f} (95% band {lo:.2f}-{hi:.2f}), ghost-target frames "
              f"{t.ghost_frames / t.frames:.2%}, frames without a target "
              f"{t.empty_frames / t.frames:.2%} of {t.frames}")


if __name__ == "__main__":
    import sys

    _print_figures("--no-motion-check" not in sys.argv)
