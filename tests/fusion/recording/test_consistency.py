"""The covariance self-check without truth (mmsnap_graph.fusion.recording.consistency):
seeded synthetic fused rows whose errors follow their covariances (it must not
fire) or covariances scaled 0.3x / 3x in sigma (it must fire, on the right side)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factors.motion import cv_process_noise, cv_transition
from mmsnap_graph.fusion.recording.consistency import (ConsistencyMonitor, fused_consistency,
                                                       INNOVATION_SIGMA_A_MPS2)

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
