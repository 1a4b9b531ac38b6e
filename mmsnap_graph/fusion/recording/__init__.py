"""A whole recording: :mod:`.sequence` (``fuse_recording``: association, the
solve, the checks), :mod:`.timing` (each node's clock brought to the
reference), :mod:`.regroup` (a node's centroids of one body merged),
:mod:`.motion_check` (rows checked against the motion of the neighbouring
frames), :mod:`.coverage` (rows a radar covering their place never sees) and
:mod:`.split_check` (one target split by the association into one-node rows).
"""
