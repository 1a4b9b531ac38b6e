"""Recording files: the HDF5 format (docs/FORMAT.md) and raw captures.

- :func:`write_recording`, :func:`update_recording`, :func:`read_recording`,
  :func:`iter_cubes`: the HDF5 recording format;
- :func:`write_fused`, :func:`read_fused`: the ``/fused`` group of one-shot estimates;
- :func:`read_dca1000_bin`, :func:`read_dca1000_sub_frame`: TI DCA1000 /
  mmWave Studio raw ADC ``.bin`` captures;
- TI data (docs/TI.md, :mod:`.ti`): :func:`read_ti_cfg` (mmWave SDK ``.cfg`` / mmWave
  Studio JSON -> one ``RadarConfig`` per sub-frame), :func:`read_ti_uart`
  (UART TLV logs), :func:`read_point_tables` (CSV / ``.npy`` / DataFrame
  point logs), :func:`recording_from_point_clouds` (3D points of mounted,
  tilted radars -> a recording).
"""

from .ti.dca1000 import (
    frame_bytes,
    iter_dca1000_frames,
    read_dca1000_bin,
    read_dca1000_sub_frame,
    recording_from_dca1000,
    sub_frame_layout,
    write_dca1000_bin,
)
from .fused import FUSED_GROUP, FUSED_LAYOUT, read_fused, write_fused
from .hdf5 import (
    FORMAT_NAME,
    FORMAT_VERSION,
    iter_cubes,
    read_cube_frames,
    read_recording,
    update_recording,
    write_recording,
)
from .ti.point_cloud import Mounting, PointCloud3D, recording_from_point_clouds
from .ti.point_table import read_point_table, read_point_tables
from .ti.cfg import (BOARD_PRESETS, BoardLayout, TiConfig, parse_ti_cfg, read_boundary_boxes,
                     read_ti_cfg)
from .ti.uart import BadFrame, UartLog, parse_ti_uart, read_ti_uart

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "write_recording",
    "update_recording",
    "read_recording",
    "iter_cubes",
    "read_cube_frames",
    "frame_bytes",
    "read_dca1000_bin",
    "iter_dca1000_frames",
    "write_dca1000_bin",
    "recording_from_dca1000",
    "read_dca1000_sub_frame",
    "sub_frame_layout",
    "BOARD_PRESETS",
    "BoardLayout",
    "TiConfig",
    "parse_ti_cfg",
    "read_ti_cfg",
    "read_boundary_boxes",
    "BadFrame",
    "UartLog",
    "parse_ti_uart",
    "read_ti_uart",
    "PointCloud3D",
    "Mounting",
    "read_point_table",
    "read_point_tables",
    "recording_from_point_clouds",
    "FUSED_GROUP",
    "FUSED_LAYOUT",
    "write_fused",
    "read_fused",
]
