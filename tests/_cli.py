"""Running the ``mmsnap`` command line inside a test."""

from __future__ import annotations

import contextlib
import dataclasses
import re
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from mmsnap_graph.app.cli import main
from mmsnap_graph.data.noise import MeasurementNoise, NodeNoiseEstimate, NoiseEstimate
from mmsnap_graph.data.recording import Detections
from mmsnap_graph.io.noise import write_noise

__all__ = ["run_cli", "error_line", "with_centroids", "store_partial_noise", "noise_block",
           "within_budget"]


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


#: A reason as the noise estimator writes it: long, with asides and a second clause.
LONG_REASON = ("two nodes' Dopplers fix each frame's velocity exactly (no cross-node check); "
               "31 usable differences of its own centroid sequence (10.3 dof); 30 dof needed")


def store_partial_noise(path) -> NoiseEstimate:
    """Write a /noise group into the two-node recording at ``path``: S1
    identifies every sigma, S2 only the range (its Doppler with
    :data:`LONG_REASON`)."""
    s1 = NodeNoiseEstimate(noise=MeasurementNoise(range_m=0.05, omega_rad=0.08, doppler_mps=0.1),
                           identified=(True,) * 3, n_residuals=(398, 399, 397),
                           method="network+temporal")
    s2 = NodeNoiseEstimate(noise=MeasurementNoise(range_m=0.06), identified=(True, False, False),
                           n_residuals=(398, 0, 0), method="network+temporal",
                           reasons=("", "no node poses for a cross-node check", LONG_REASON))
    est = NoiseEstimate(nodes={"S1": s1, "S2": s2}, method="network+temporal")
    write_noise(path, est)
    return est


def noise_block(out: str) -> list[str]:
    """The printed /noise block of ``store_partial_noise``'s estimate, checked:
    a header, one short line per node with every sigma and its unit, the
    unidentified ones marked, then their reasons, short, one line each."""
    lines = out.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("sigmas from /noise"))
    block = lines[start:start + 5]
    assert "* = not identified" in block[0], block
    assert all(len(ln) <= 100 for ln in block), block
    assert re.match(r"  S1  range 0\.05 m +omega 0\.08 rad +Doppler 0\.1 m/s +"
                    r"estimated from 397-399 residuals$", block[1]), block
    assert re.match(r"  S2  range 0\.06 m +omega 0\.785 rad\* +Doppler 0\.181 m/s\* +"
                    r"not identified: omega \(a\), Doppler \(b\)$", block[2]), block
    assert block[3:] == ["  (a) no node poses for a cross-node check",
                         "  (b) two nodes' Dopplers fix each frame's velocity exactly"], block
    return block


def mmsnap(*argv: str) -> subprocess.Popen:
    """``python -m mmsnap_graph ARGV`` started in a child process (text pipes)."""
    return subprocess.Popen([sys.executable, "-m", "mmsnap_graph", *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def simulated(path: Path, n_frames: int) -> Path:
    """A clean-model network B random walk of ``n_frames`` centroid frames
    (seed 2) written to ``path``."""
    assert main(["simulate", "--model", "clean", "-c", "B", "-t", "random", "-n", str(n_frames),
                 "-l", "centroids", "--seed", "2", "-o", str(path), "--no-progress"]) == 0
    return path


def _cpu_s() -> float:
    """CPU seconds of this process (all its threads) and of its reaped children."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


class _Hung(Exception):
    pass


@contextlib.contextmanager
def within_budget(what, cpu_s: float = 15.0, hang_s: float = 300.0):
    """Fail (naming ``what``) if the block's work exceeds ``cpu_s`` seconds of
    CPU time (this process's threads and the children it waited for), or if it
    has not returned after ``hang_s`` seconds of wall time: a hang, a blocked
    command that uses no CPU. CPU time, not wall time, bounds the work, so a
    loaded machine does not fail it; the wall-time alarm (a SIGALRM timer, in
    the main thread) stops a hang with a failure instead of stopping the suite,
    generous enough that a slow machine is not one."""
    armed = threading.current_thread() is threading.main_thread()
    if armed:
        def on_alarm(signum, frame):
            raise _Hung
        previous = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, hang_s)
    start_cpu, start_wall = _cpu_s(), time.monotonic()
    try:
        yield
    except _Hung:
        raise AssertionError(f"{what}: no return after {hang_s:.0f} s (a hang)") from None
    finally:
        if armed:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    used, wall = _cpu_s() - start_cpu, time.monotonic() - start_wall
    assert wall < hang_s, f"{what}: {wall:.0f} s of wall time (a hang)"
    assert used < cpu_s, f"{what}: {used:.1f} s of CPU time, more than {cpu_s:.0f} s"
