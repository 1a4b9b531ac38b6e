"""Recording files: the HDF5 format (docs/FORMAT.md) and raw captures.

- :func:`write_recording`, :func:`update_recording`, :func:`read_recording`,
  :func:`iter_cubes`: the HDF5 recording format;
- :func:`write_fused`, :func:`read_fused`: the ``/fused`` group of one-shot estimates;
- :func:`read_dca1000_bin`: TI DCA1000 / mmWave Studio raw ADC ``.bin`` captures.
"""

from .dca1000 import (
    frame_bytes,
    iter_dca1000_frames,
    read_dca1000_bin,
    recording_from_dca1000,
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
    "FUSED_GROUP",
    "FUSED_LAYOUT",
    "write_fused",
    "read_fused",
]
