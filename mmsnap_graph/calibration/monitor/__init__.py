"""Noticing a moved radar and re-calibrating it.

- :mod:`.decalibration`: :class:`~.decalibration.DecalibrationMonitor` and
  :func:`~.decalibration.monitor_recording`;
- :mod:`.stats`: the per-frame information and score of a node's pose error
  and the window test.

The public names are exported by :mod:`mmsnap_graph.calibration`.
"""
