"""``mmsnap demo`` runs through the CLI entry point and reports honest figures."""

from __future__ import annotations

import re

import numpy as np

from mmsnap_graph.cli import main
from mmsnap_graph.commands.demo import simulate_sequence


def test_demo_runs_through_the_cli(capsys):
    assert main(["demo", "--frames", "6", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "configuration B" in out
    rows = [line for line in out.splitlines() if re.match(r"\s+\d+\s+-?\d", line)]
    assert len(rows) == 6
    rmse = {m.group(1): (float(m.group(2)), float(m.group(3)))
            for m in re.finditer(r"(MAP|ML)\s+RMSE over 6 frames: position ([\d.]+) m, velocity ([\d.]+) m/s", out)}
    assert set(rmse) == {"MAP", "ML"}
    bound = re.search(r"bound: position ([\d.]+) m, velocity ([\d.]+) m/s", out)
    pos_bound, vel_bound = float(bound.group(1)), float(bound.group(2))
    # 6 frames: the RMSE is within a factor ~2 of the bound, not orders of magnitude
    for pos, vel in rmse.values():
        assert pos_bound / 3 < pos < 3 * pos_bound
        assert vel_bound / 3 < vel < 3 * vel_bound


def test_demo_is_seeded():
    a = simulate_sequence(5, 7, 0.15)
    b = simulate_sequence(5, 7, 0.15)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    truth = a[0]
    np.testing.assert_allclose(np.diff(truth[:, :2], axis=0), 0.15 * truth[1:, 2:], atol=1e-12)


def test_demo_rejects_bad_arguments(capsys):
    assert main(["demo", "--frames", "0"]) == 2
    assert "--frames must be >= 1, got 0" in capsys.readouterr().err
