"""The boxes of TI people-tracking ``.cfg`` files (io.ti.cfg.read_boundary_boxes)."""

from __future__ import annotations

import pytest

from mmsnap_graph.errors import ConfigurationError, FileFormatError
from mmsnap_graph.io.ti.cfg import read_boundary_boxes


def test_boxes_of_the_3d_and_2d_people_tracking_demos(tmp_path):
    cfg = tmp_path / "people.cfg"
    cfg.write_text("sensorStop\n% boxes\nboundaryBox -4 4 0.5 7.5 0 3   % room\n"
                   "staticBoundaryBox -3 3 0.5 7.5 0 3\npresenceBoundaryBox -3 3 0.5 7.5 0 3\n"
                   "boundaryBox -2 1.6 0 3.6 0 2\n")           # the last one counts
    boxes = read_boundary_boxes(cfg)
    assert boxes == {"boundaryBox": (-2.0, 1.6, 0.0, 3.6, 0.0, 2.0),
                     "staticBoundaryBox": (-3.0, 3.0, 0.5, 7.5, 0.0, 3.0),
                     "presenceBoundaryBox": (-3.0, 3.0, 0.5, 7.5, 0.0, 3.0)}
    flat = tmp_path / "pplcount.cfg"
    flat.write_text("boundaryBox -6 6 0.5 10\n")
    assert read_boundary_boxes(flat) == {"boundaryBox": (-6.0, 6.0, 0.5, 10.0)}
    none = tmp_path / "oob.cfg"
    none.write_text("sensorStart\n")
    assert read_boundary_boxes(none) == {}


@pytest.mark.parametrize("line, words", [("boundaryBox -4 4 0.5", "4 or 6 finite numbers"),
                                         ("boundaryBox -4 4 x 7", "must be numbers"),
                                         ("staticBoundaryBox 4 -4 0 7", "minimum must be below"),
                                         ("boundaryBox -4 4 0 nan", "4 or 6 finite")])
def test_bad_boxes_name_the_file_and_line(tmp_path, line, words):
    cfg = tmp_path / "bad.cfg"
    cfg.write_text(f"sensorStop\n{line}\n")
    with pytest.raises(ConfigurationError, match=f"bad.cfg line 2: .*{words}"):
        read_boundary_boxes(cfg)


def test_a_missing_file_is_a_file_format_error(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read"):
        read_boundary_boxes(tmp_path / "none.cfg")
