"""docs/FORMAT.md quotes the extension-group layouts the code writes."""

from pathlib import Path

from mmsnap_graph.io.calibration import CALIBRATION_LAYOUT
from mmsnap_graph.fusion.sequence import FUSED_LAYOUT

FORMAT_MD = Path(__file__).resolve().parents[1] / "docs" / "FORMAT.md"


def test_format_doc_quotes_the_extension_layouts():
    text = FORMAT_MD.read_text()
    for layout in (CALIBRATION_LAYOUT, FUSED_LAYOUT):
        assert layout.rstrip() in text
