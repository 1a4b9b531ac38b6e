"""One frame at a time: :mod:`.frame_stream` (``FrameStream``, per-frame
fusion and tracking as measurements arrive) and :mod:`.association` (the
association's decisions on the fast path).
"""
