"""The walkthrough notebooks run top to bottom (nbclient), on a short stretch
of the sample data, so they never rot."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
#: Frames of the sample recordings the notebooks use under test.
TEST_FRAMES = "150"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["calibration_walkthrough.ipynb", "oneshot_walkthrough.ipynb",
                                  "ti_point_cloud_walkthrough.ipynb"])
def test_notebook_executes(name, monkeypatch):
    path = NOTEBOOKS / name
    nb = nbformat.read(path, as_version=4)
    assert nb.metadata["kernelspec"]["name"] == "python3"
    # The kernel is launched as "python" from the PATH: make it this interpreter.
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ["PATH"])
    monkeypatch.setenv("MMSNAP_NB_FRAMES", TEST_FRAMES)
    client = nbclient.NotebookClient(nb, timeout=60, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    # Figures were produced.
    assert any("image/png" in o.get("data", {}) for o in outputs)
