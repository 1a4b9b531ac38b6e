"""The package's public API, and what its layering means at run time.

The static import graph (layer order, cycles, private names) is checked by
tests/test_structure.py with tools/check_structure.py; this file checks what
the interpreter actually loads."""

import subprocess
import sys

import pytest

import mmsnap_graph
import mmsnap_graph.tracking


@pytest.mark.parametrize("module", [mmsnap_graph, mmsnap_graph.tracking])
def test_every_public_name_resolves(module):
    for name in module.__all__:
        assert getattr(module, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute"):
        module.not_a_name  # noqa: B018


@pytest.mark.slow
def test_signal_chain_and_simulator_do_not_import_gtsam():
    code = ("import sys, mmsnap_graph, mmsnap_graph.app.pipeline, mmsnap_graph.sim, "
            "mmsnap_graph.tracking.ekf, mmsnap_graph.io; "
            "print('gtsam' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
