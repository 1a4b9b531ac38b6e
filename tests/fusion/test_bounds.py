"""Cramer-Rao and Bayesian bounds (mmsnap_graph.fusion.bounds): their order,
the singular Fisher information of a degenerate geometry, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from _shared import PAPER_NOISE, PAPER_PRIOR, POSES_B, POSES_C
from mmsnap_graph.errors import GeometryError, ValidationError
from mmsnap_graph.fusion.bounds import bayesian_bound, cramer_rao_bound, fisher_information

TRUTH_B = np.array([0.5, 4.5, 0.6, -0.4])
#: On the line through C's two radars: the cross-line velocity vx is
#: unobservable from Doppler.
TRUTH_C = np.array([0.0, 3.5, 0.8, 0.5])


def test_bounds_order_and_singularity():
    crb = cramer_rao_bound(TRUTH_B, POSES_B, PAPER_NOISE)
    bb = bayesian_bound(TRUTH_B, POSES_B, PAPER_NOISE, PAPER_PRIOR)
    # the prior only adds information: CRB - BB is positive semidefinite
    assert np.linalg.eigvalsh(crb - bb).min() > -1e-15
    assert_allclose(np.linalg.inv(bb), fisher_information(TRUTH_B, POSES_B, PAPER_NOISE) + PAPER_PRIOR.information, rtol=1e-9)
    # on the line through C's radars vx does not enter any measurement
    info = fisher_information(TRUTH_C, POSES_C, PAPER_NOISE)
    assert_allclose(info[2], 0.0, atol=1e-12)
    with pytest.raises(GeometryError, match="Fisher information is singular"):
        cramer_rao_bound(TRUTH_C, POSES_C, PAPER_NOISE)
    bb_c = bayesian_bound(TRUTH_C, POSES_C, PAPER_NOISE, PAPER_PRIOR)
    assert bb_c[2, 2] == pytest.approx(3.5**2, rel=1e-9)  # vx: the prior alone
    # a missing node removes its information
    assert_allclose(fisher_information(TRUTH_B, POSES_B, PAPER_NOISE, np.array([True, False])), fisher_information(TRUTH_B, POSES_B[:1], PAPER_NOISE))


def test_bounds_reject_bad_input():
    with pytest.raises(GeometryError, match=r"state position \[5.0, 5.0\] is at observed node 1's position"):
        cramer_rao_bound([5.0, 5.0, 0, 0], POSES_B, PAPER_NOISE)
    with pytest.raises(ValidationError, match=r"state must have shape \(4,\)"):
        bayesian_bound([1.0, 2.0], POSES_B, PAPER_NOISE, PAPER_PRIOR)
    with pytest.raises(ValidationError, match="prior must be a GaussianPrior"):
        bayesian_bound(TRUTH_B, POSES_B, PAPER_NOISE, None)
    with pytest.raises(ValidationError, match=r"node_poses must have shape \(N, 3\)"):
        fisher_information(TRUTH_B, [1.0, 2.0, 3.0], PAPER_NOISE)
