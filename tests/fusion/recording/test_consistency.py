"""The covariance self-check without truth (mmsnap_graph.fusion.recording.consistency):
seeded synthetic fused rows whose errors follow their covariances (it must not
fire) or covariances scaled 0.3x / 3x in sigma (it must fire, on the right side)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factors.motion import cv_process_noise, cv_transition
from mmsnap_graph.fusion.recording.consistency import (ConsistencyMonitor, fused_consistency,
                                                       INNOVATION_SIGMA_A_MPS2, MAX_GAP_S)

from ..._fused_rows import fused_rows

PERIOD_S = 0.05


def _walk(seed: int, k: int = 400, *, scale: float = 1.0):
    """One walker at 20 fps whose rows' errors follow their covariance and
    whose cross-node costs follow their chi-square; covariances and costs
    reported as if the sigmas were ``scale`` times the true ones."""
    rng = np.random.default_rng(seed)
    x = np.array([1.0, 3.0, 0.8, 0.0])
    tr = cv_transition(PERIOD_S)
    q = cv_process_noise(PERIOD_S, INNOVATION_SIGMA_A_MPS2)
    truth = []
    for _ in range(k):
        x = tr @ x + rng.multivariate_normal(np.zeros(4), q)
        truth.append(x)
    truth = np.array(truth)
    cov = np.diag([0.12, 0.12, 0.4, 0.4]) ** 2
    est = truth + rng.multivariate_normal(np.zeros(4), cov, size=k)
    nodes = np.where(rng.random(k) < 0.2, 1, 2)
    # 2 nodes: 3 * 2 - 4 = 2 dof left, twice the cost chi-square(2).
    cost = 0.5 * rng.chisquare(2, size=k) / scale**2
    f = fused_rows(np.arange(k), est[:, :2], nodes=nodes, velocity=est[:, 2:], cost=cost)
    c = np.tile(cov * scale**2, (k, 1, 1))
    return dataclasses.replace(f, covariance=c, laplace_covariance=c, frame_period_s=PERIOD_S,
                               track_id=np.zeros(k, np.int64))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_consistent_rows_pass(seed):
    r = fused_consistency(_walk(seed))
    assert r.verdict == "consistent", r
    assert 1.6 < r.innovation_nis < 2.4 and 0.8 < r.residual_ratio < 1.2
    assert r.consistent is True and not r.reasons


@pytest.mark.parametrize("seed", [0, 1])
def test_sigmas_scaled_down_fire_over_confident(seed):
    r = fused_consistency(_walk(seed, scale=0.3))
    assert r.verdict == "over-confident" and r.consistent is False
    assert r.residual_ratio > 5 and len(r.reasons) == 2  # both statistics say so


@pytest.mark.parametrize("seed", [0, 1])
def test_sigmas_scaled_up_fire_under_confident(seed):
    r = fused_consistency(_walk(seed, scale=3.0))
    assert r.verdict == "under-confident" and r.consistent is False and r.residual_ratio < 0.2


def test_rows_seen_by_one_radar_alone_are_judged_by_the_innovations():
    f = _walk(0)
    one = dataclasses.replace(f, observed=np.c_[f.observed[:, 0], np.zeros(len(f), bool)])
    bad = dataclasses.replace(one, covariance=one.covariance * 0.09)
    assert fused_consistency(one).verdict == "consistent"
    r = fused_consistency(bad)
    assert r.n_residual_rows == 0 and r.verdict == "over-confident"


def test_an_error_that_stays_from_frame_to_frame_is_seen_by_the_residuals():
    """A bias the innovations cannot see (the same in every frame: a pose
    off) makes the nodes disagree: the residuals fire alone."""
    f = _walk(1)
    biased = dataclasses.replace(f, final_cost=f.final_cost * 4.0)
    r = fused_consistency(biased)
    assert r.verdict == "over-confident" and len(r.reasons) == 1
    assert "nodes disagree" in r.reasons[0]


def test_windows_give_the_whole_sequences_report():
    f = _walk(3)
    whole = fused_consistency(f)
    m = ConsistencyMonitor()
    for lo in range(0, len(f), 130):
        keep = slice(lo, lo + 130)
        m.add(dataclasses.replace(f, **{k: getattr(f, k)[keep] for k in (
            "frame", "target", "label", "detection_index", "observed", "state", "covariance",
            "laplace_covariance", "success", "status", "message", "iterations", "final_cost",
            "degeneracy", "track_id", "rejected") if getattr(f, k) is not None}))
    got = m.report()
    assert got.verdict == whole.verdict and got.n_innovations == whole.n_innovations
    assert got.innovation_nis == pytest.approx(whole.innovation_nis, rel=1e-12)
    assert got.residual_ratio == pytest.approx(whole.residual_ratio, rel=1e-12)


def test_few_rows_say_not_enough_data():
    f = _walk(0, k=12)
    r = fused_consistency(f)
    assert r.verdict == "not enough data" and r.consistent is None
    assert r.to_dict()["consistent"] is None


def test_rows_given_frame_by_frame_give_the_whole_sequences_report():
    """add_rows, one frame at a time (the streaming commands), is add."""
    f = _walk(4, k=200)
    whole = fused_consistency(f)
    m = ConsistencyMonitor()
    kept = f.observed & ~f.rejected if f.rejected is not None else f.observed
    for i in range(len(f)):
        m.add_rows(f.frame[i:i + 1], f.state[i:i + 1], f.covariance[i:i + 1],
                   success=f.success[i:i + 1], track_id=f.track_id[i:i + 1],
                   n_kept=kept[i:i + 1].sum(axis=1), final_cost=f.final_cost[i:i + 1],
                   frame_period_s=f.frame_period_s)
    got = m.report()
    assert got.n_innovations == whole.n_innovations and got.verdict == whole.verdict
    assert got.innovation_nis == pytest.approx(whole.innovation_nis, rel=1e-12)
    assert got.residual_ratio == pytest.approx(whole.residual_ratio, rel=1e-12)


def test_memory_is_bounded_by_the_live_tracks():
    """Running sums, and a filter only for each track seen within MAX_GAP_S:
    10 000 rows of 2 000 short-lived people keep a handful of filters."""
    rng = np.random.default_rng(0)
    m = ConsistencyMonitor()
    frames = np.arange(10_000)
    m.add_rows(frames, rng.normal(size=(frames.size, 4)), np.tile(np.eye(4), (frames.size, 1, 1)),
               track_id=frames // 5, frame_period_s=PERIOD_S)
    assert len(m._filters) <= MAX_GAP_S / PERIOD_S + 2
    assert m.report().n_innovations == 10_000 - 2_000
    assert not any(isinstance(v, list) and len(v) > 100 for v in vars(m).values()
                   if not isinstance(v, dict))


def test_new_verdict_says_only_changes_and_the_warning_is_one_sentence():
    good, low = _walk(5), _walk(5, scale=0.3)
    m = ConsistencyMonitor()
    said = []
    for lo in range(0, len(good), 10):
        m.add(_rows(good, slice(lo, lo + 10)))
        r = m.new_verdict()
        if r is not None:
            said.append(r.verdict)
    assert said == ["consistent"]          # once, when there was enough data
    assert m.report().warning is None
    m2 = ConsistencyMonitor()
    m2.add(low)
    r = m2.new_verdict()
    assert r.verdict == "over-confident" and m2.new_verdict() is None
    assert r.warning.startswith("warning: the fused covariances are over-confident for this "
                                "recording's data: ")
    assert r.warning.count("\n") == 0 and all(why in r.warning for why in r.reasons)
    assert fused_consistency(_walk(5, k=10)).warning is None  # not enough data: silent


def _rows(f, keep):
    return dataclasses.replace(f, **{k: getattr(f, k)[keep] for k in (
        "frame", "target", "label", "detection_index", "observed", "state", "covariance",
        "laplace_covariance", "success", "status", "message", "iterations", "final_cost",
        "degeneracy", "track_id", "rejected") if getattr(f, k) is not None})


@pytest.mark.parametrize("scale,fires", [(1.0, None), (0.3, "over-confident"),
                                         (3.0, "under-confident")])
def test_firing_rate_over_seeds(scale, fires):
    """Seeded Monte Carlo of the synthetic walker (50 seeds, 400 rows each):
    right covariances fire on at most 2 of 50 (4%; measured 0), 0.3x or 3x
    sigmas on at least 48 of 50 (measured 50), on the right side."""
    verdicts = [fused_consistency(_walk(1000 + s, scale=scale)).verdict for s in range(50)]
    if fires is None:
        assert sum(v != "consistent" for v in verdicts) <= 2, verdicts
    else:
        assert sum(v == fires for v in verdicts) >= 48, verdicts
