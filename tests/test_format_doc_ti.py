"""docs/FORMAT.md documents what TI imports write (issue 14): every optional
RadarConfig attribute the HDF5 writer may add and every /metadata key of
`mmsnap import`. Before, the page listed the radar attributes as "all
required" (the TI fields were missing) and named no import metadata; it also
pointed at modules that the redesign moved."""

from __future__ import annotations

import re

from mmsnap_graph.app.cli import main
from mmsnap_graph.data.radar_config import OPTIONAL_FIELD_DEFAULTS
from mmsnap_graph.io import read_recording

from _shared import ROOT, TI_DATA

FORMAT_MD = (ROOT / "docs" / "FORMAT.md").read_text()


def _documented_names() -> set[str]:
    return set(re.findall(r"^\| `([^`]+)`", FORMAT_MD, flags=re.M)) | {
        name for row in re.findall(r"^\| (`[^|]+`)(?:, `[^|]+`)* \|", FORMAT_MD, flags=re.M)
        for name in re.findall(r"`([^`]+)`", row)}


def test_every_optional_radar_attribute_is_documented():
    names = _documented_names()
    missing = sorted(set(OPTIONAL_FIELD_DEFAULTS) - names)
    assert not missing, missing


def test_modules_the_page_names_exist():
    for path in re.findall(r"`(mmsnap_graph/[\w/]+\.py)`", FORMAT_MD):
        assert (ROOT / path).is_file(), path


def test_every_metadata_key_of_the_imports_is_documented(tmp_path):
    out = tmp_path / "t.h5"
    assert main(["import", "table", "--table", str(TI_DATA / "points_sensor_frame.csv"),
                 "--frame-period", "0.05", "--mount", "S1=0.8,5", "--mount", "S2=1.2,15",
                 "--accumulate", "2", "-o", str(out)]) == 0
    keys = set(read_recording(out).metadata)
    out2 = tmp_path / "d.h5"
    assert main(["import", "dca1000", "--cfg", str(TI_DATA / "dca1000_fast.cfg"), "--board",
                 "AWR1843BOOST", "--node", f"S1={TI_DATA / 'dca1000_fast.bin'}", "-o",
                 str(out2)]) == 0
    keys |= set(read_recording(out2).metadata)
    out3 = tmp_path / "a.h5"
    assert main(["import", "dca1000", "--cfg", str(TI_DATA / "dca1000_small.cfg"), "--board",
                 "AWR1843BOOST", "--sub-frame", "1", "--node",
                 f"S1={TI_DATA / 'dca1000_small.bin'}", "-o", str(out3)]) == 0
    advanced = read_recording(out3).metadata
    assert advanced["sub_frame"] == 1                      # which sub-frame it is
    keys |= set(advanced)
    names = _documented_names()
    generic = {k.replace("S1_", "<node>_").replace("S2_", "<node>_") for k in keys}
    missing = sorted(generic - names)
    assert not missing, missing


def test_the_python_names_of_docs_ti_are_in_mmsnap_graph_io():
    """docs/TI.md says its readers are in ``mmsnap_graph.io``; before, only
    the DCA1000 reader was (the TI .cfg, UART and table readers had to be
    imported from private-looking submodules)."""
    import mmsnap_graph.io as io
    text = (ROOT / "docs" / "TI.md").read_text()
    called = set(re.findall(r"`(read_\w+|parse_\w+|recording_from_\w+)\(", text))
    named = {"TiConfig", "BoardLayout", "PointCloud3D", "Mounting"} & set(
        re.findall(r"`(\w+)`", text))
    assert called >= {"read_ti_cfg", "read_dca1000_sub_frame", "read_point_tables"}
    missing = sorted(n for n in called | named if not hasattr(io, n))
    assert not missing, missing
    assert set(io.__all__) >= called | named
