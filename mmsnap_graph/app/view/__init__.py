"""Looking at the fused people: a Foxglove / Lichtblick log and live stream
(:mod:`.foxglove_log`, ``mmsnap live --view``, ``mmsnap replay --view``), a
figure of a recording (:mod:`.plot`, ``mmsnap plot``), and the geometry both
draw (:mod:`.scene`)."""
