"""The importers' input files (mmsnap_graph.io.ti.inputs): a regular file or a link to
one is read; a missing path, a folder or a pipe is an error naming what it is
(reading a pipe would wait for ever)."""

from __future__ import annotations

import pytest

from mmsnap_graph.errors import FileFormatError
from mmsnap_graph.io.ti.uart import read_ti_uart


def test_a_pipe_or_folder_is_named_not_read(tmp_path):
    import os
    from mmsnap_graph.io.ti.point_table import read_point_tables
    from mmsnap_graph.io.ti.cfg import read_ti_cfg
    from mmsnap_graph.io.ti.uart import read_ti_uart
    fifo = tmp_path / "pipe.bin"
    os.mkfifo(fifo)
    for read, kind in ((read_ti_uart, "UART log"), (read_point_tables, "point table"),
                       (lambda p: read_ti_cfg(p, board="AWR1843BOOST"), "configuration file")):
        with pytest.raises(FileFormatError, match=rf"{kind} .*pipe.bin is not a regular file"):
            read(fifo)
        with pytest.raises(FileFormatError, match=rf"{kind} .* is a folder"):
            read(tmp_path)
        with pytest.raises(FileFormatError, match=rf"{kind} .*gone.bin does not exist"):
            read(tmp_path / "gone.bin")


def test_require_file_passes_files_and_links_to_them_and_names_the_rest(tmp_path):
    import os

    from mmsnap_graph.io.ti.inputs import require_file

    f = tmp_path / "log.bin"
    f.write_bytes(b"x")
    link = tmp_path / "link.bin"
    link.symlink_to(f)
    assert require_file(f, "UART log") == f
    assert require_file(str(link), "UART log") == link          # a str is taken too
    dangling = tmp_path / "dangling.bin"
    dangling.symlink_to(tmp_path / "gone.bin")
    folder_link = tmp_path / "folder_link"
    folder_link.symlink_to(tmp_path)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for path, what in ((dangling, "does not exist"), (folder_link, "is a folder"),
                       (fifo, "is not a regular file (a pipe or a device?)")):
        with pytest.raises(FileFormatError) as err:
            require_file(path, "capture file")
        assert str(err.value) == f"capture file {path} {what}"
