"""A whole recording: :mod:`.sequence` (``fuse_recording``: association, the
solve, the checks), :mod:`.timing` (each node's clock brought to the
reference), :mod:`.motion_check` (rows checked against the motion of the
neighbouring frames) and :mod:`.split_check` (one target split by the
association into one-node rows).
"""
