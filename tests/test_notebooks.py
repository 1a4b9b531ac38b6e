"""The walkthrough notebooks: stored executed (their outputs and figures are
in the files, readable without running them), with no link or path outside
the repository and only the public API; and they still run top to bottom
(nbclient, on a short stretch of the sample data), so they never rot."""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

from _shared import ROOT

NOTEBOOKS = ROOT / "notebooks"
NAMES = ["calibration_walkthrough.ipynb", "oneshot_walkthrough.ipynb",
         "ti_point_cloud_walkthrough.ipynb"]
#: Frames of the sample recordings the notebooks use under test.
TEST_FRAMES = "150"
#: Markdown links: [text](target).
_LINK = re.compile(r"\]\(([^)\s]+)\)")


def _cells(name: str) -> list[dict]:
    return json.loads((NOTEBOOKS / name).read_text(encoding="utf-8"))["cells"]


def _source(cell: dict) -> str:
    return "".join(cell["source"])


@pytest.mark.parametrize("name", NAMES)
def test_stored_notebook_is_executed_with_its_figures_and_no_error(name):
    code = [c for c in _cells(name) if c["cell_type"] == "code"]
    assert all(c.get("execution_count") for c in code), "a code cell was not run"
    outputs = [o for c in code for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "no figure stored"
    assert not [o for o in outputs if o.get("name") == "stderr"], "warnings or bars stored"
    printed = "".join("".join(o.get("text", "")) for o in outputs)
    assert len(printed) < 10_000, "keep the printed output short"


def test_stored_notebooks_stay_small():
    total = sum((NOTEBOOKS / n).stat().st_size for n in NAMES)
    assert total < 3_000_000, f"{total} bytes: store smaller figures"


@pytest.mark.parametrize("name", NAMES)
def test_notebook_links_stay_in_the_repository_and_it_uses_the_public_api(name):
    for cell in _cells(name):
        text = _source(cell)
        assert not re.search(r"shared/|/work/|/tmp/|/home/", text), text
        if cell["cell_type"] == "markdown":
            for target in _LINK.findall(text):
                assert not re.match(r"[a-z]+://", target), f"outside link {target}"
                path = (NOTEBOOKS / target.split("#")[0]).resolve()
                assert path.is_relative_to(ROOT) and path.exists(), target
        else:
            assert "app.demo" not in text and "import demo" not in text and "demo." not in text


def test_ti_notebook_fuses_with_the_noise_from_the_data_and_shows_reported_vs_actual():
    text = "\n".join(_source(c) for c in _cells("ti_point_cloud_walkthrough.ipynb"))
    assert "estimate_noise(" in text and "noise=noise.per_node" in text
    printed = "".join("".join(o.get("text", "")) for c in _cells("ti_point_cloud_walkthrough.ipynb")
                      if c["cell_type"] == "code" for o in c.get("outputs", []))
    for label in ("noise from the data", "paper's sigmas"):
        line = next(ln for ln in printed.splitlines() if ln.startswith(label))
        actual = float(re.search(r"error RMS ([0-9.]+) cm", line).group(1))
        reported = float(re.search(r"reported sigma median ([0-9.]+) cm", line).group(1))
        if label == "noise from the data":  # the reported uncertainty describes the error
            assert 0.5 < reported / actual < 2.0, line


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_notebook_executes(name, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    path = NOTEBOOKS / name
    nb = nbformat.read(path, as_version=4)
    assert nb.metadata["kernelspec"]["name"] == "python3"
    # The kernel is launched as "python" from the PATH: make it this interpreter.
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ["PATH"])
    monkeypatch.setenv("MMSNAP_NB_FRAMES", TEST_FRAMES)
    client = nbclient.NotebookClient(nb, timeout=120, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    # Figures were produced.
    assert any("image/png" in o.get("data", {}) for o in outputs)
