"""The commands that move files in and out of the recording format:
``mmsnap import`` (TI captures, tables and logs in), ``mmsnap export``
(``/fused`` and ``/calibration`` out as CSV or JSON lines) and ``mmsnap
info`` (what a recording holds)."""
