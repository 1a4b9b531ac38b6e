"""The physics layer (``factors``): its public API resolves, it imports
nothing from :mod:`mmsnap_graph`, and its numpy part loads without GTSAM."""

import ast
import pathlib
import subprocess
import sys

import pytest

import factors

FACTORS_DIR = pathlib.Path(factors.__file__).parent


def test_every_public_name_of_factors_resolves():
    for name in factors.__all__:
        assert getattr(factors, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute"):
        factors.not_a_name  # noqa: B018


@pytest.mark.parametrize("path", sorted(FACTORS_DIR.glob("*.py")), ids=lambda p: p.name)
def test_factors_do_not_import_mmsnap_graph(path):
    tree = ast.parse(path.read_text())
    imported = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    imported += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 0]
    assert not [m for m in imported if m.split(".")[0] == "mmsnap_graph"], path.name


@pytest.mark.slow
def test_numpy_part_of_factors_and_the_local_tracker_load_without_gtsam():
    code = ("import sys, factors, factors.models, factors.motion, factors.robust, "
            "mmsnap_graph.radar.cluster, mmsnap_graph.sim.simulator, mmsnap_graph.tracking.ekf; "
            "factors.detection_covariance_global(3.0, 0.2, [0.0, 0.0, 0.0], 0.05, 0.1); "
            "print('gtsam' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
