"""Running the ``mmsnap`` command line inside a test."""

from __future__ import annotations

import dataclasses

from mmsnap_graph.app.cli import main
from mmsnap_graph.data.recording import Detections

__all__ = ["run_cli", "error_line", "with_centroids"]


def run_cli(capsys, *argv):
    """``(exit code, stdout, stderr)`` of ``mmsnap ARGV`` (argparse's own
    exits included); the arguments may be paths or numbers."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse: a value of the wrong type or choice
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def error_line(err: str) -> str:
    """The one error line (argparse prints its usage before it)."""
    lines = [ln for ln in err.strip().splitlines() if ": error: " in ln]
    assert len(lines) == 1 and lines[0] == err.strip().splitlines()[-1], err
    return lines[0]


def with_centroids(rec, node_index: int, edit) -> object:
    """``rec`` with node ``node_index``'s centroid columns changed by
    ``edit(range_m, omega_rad, doppler_mps)`` (in place on copies)."""
    name = rec.node_names[node_index]
    c = rec.nodes[name].centroids
    r, w, v = c.range_m.copy(), c.omega_rad.copy(), c.doppler_mps.copy()
    edit(r, w, v)
    d = Detections(frame=c.frame, range_m=r, omega_rad=w, doppler_mps=v, snr_db=c.snr_db,
                   target_id=c.target_id)
    return rec.with_node(dataclasses.replace(rec.nodes[name], centroids=d))
