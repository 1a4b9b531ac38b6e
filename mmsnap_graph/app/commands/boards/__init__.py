"""The verbs of live TI boards (docs/LIVE.md): ``mmsnap record`` (boards ->
one recording on the host's clock) and ``mmsnap live`` (boards -> fused
people as they walk); :mod:`.board_args` holds the options both take."""
