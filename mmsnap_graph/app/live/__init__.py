"""Live fusion of TI boards (docs/LIVE.md): :mod:`.driver` groups the boards'
frames on the common clock and runs the per-node chain and the stream's
fusion and tracker; :mod:`.sinks` are what takes each fused frame (JSON lines,
the recording of ``--record``; a view plugs in the same way)."""
