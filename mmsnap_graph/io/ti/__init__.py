"""TI radar data (docs/TI.md): the formats TI's tools write, read into the
project's records.

- :mod:`.cfg`: mmWave SDK ``.cfg`` files and mmWave Studio JSON -> one
  ``RadarConfig`` per sub-frame (:func:`read_ti_cfg`), board layouts, the
  room's boundary boxes; :mod:`.cfg_fields`: each command's arguments and
  their hardware limits;
- :mod:`.uart`: logs of a demo's data UART (:func:`read_ti_uart`), read by the
  parser of live boards, :mod:`.serial` (docs/LIVE.md);
- :mod:`.dca1000`: DCA1000 / mmWave Studio raw ADC ``.bin`` captures;
- :mod:`.point_table`: point logs as CSV, ``.npy``/``.npz`` or a DataFrame
  (:func:`read_point_tables`);
- :mod:`.point_cloud`: 3D points of mounted, tilted radars projected into a
  recording (:func:`recording_from_point_clouds`);
- :mod:`.inputs`: the input files (a regular file, or an error naming what
  the path is).

The readers are also importable from :mod:`mmsnap_graph.io`.
"""
