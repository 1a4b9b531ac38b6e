"""Emulated TI boards on real pseudo-terminal pairs (tests only).

An :class:`EmulatedBoard` owns two pty pairs in raw mode: its CLI port
answers as a TI demo does (the echoed line, ``Done``, the prompt
``mmwDemo:/>``, ``Error -1`` for a line it refuses, ``'...' is not
recognized as a CLI command`` for an unknown command, ``Ignored: Sensor is
already stopped``, and a garbled first reply after power-up), and its data
port plays a list of UART packets at the real frame rate once ``sensorStart``
came (or at once for a board without a CLI port). The program under test
opens the slave ends (``cli_port``, ``data_port``) with pyserial, as it would
a USB serial device. :func:`board_packets` makes the packets from simulated
point clouds (tests/ti_samples.py, tests/ti_encode.py).

Boards that look at one walk share a :class:`Scene`: packet ``i`` of every
board is the world at the scene's time ``i * frame_period_s``, and a board
started later (a program configures its boards one after the other) streams
the scene from then on, as real boards looking at one person do. Without a
scene each board plays its walk from its own ``sensorStart``: two such boards
show the person in two places at once.

Synchronisation is by events and the board's own log of what it did
(``commands``, ``write_times``), never by sleeping in the test.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
import tty

import math

import numpy as np

from ti_encode import encode_oob_frame, encode_tracking_frame
from ti_samples import FRAME_PERIOD_S, MOUNTS, lift, simulated

PROMPT = b"mmwDemo:/>"


class Scene:
    """The world several boards look at (module docstring): it starts at the
    first ``sensorStart`` of a board that shares it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.start: float | None = None     # host monotonic time of packet 0

    def begin(self, now: float) -> float:
        """The scene's start (``now`` for the first board that starts)."""
        with self._lock:
            if self.start is None:
                self.start = now
            return self.start


class EmulatedBoard:
    """One board (module docstring).

    packets : the data port's packets, one per frame, in order.
    cli : whether the board has a CLI port (False: it streams from the start).
    garbled_first : the first command after power-up comes back garbled.
    start_delay_s : the data port starts this long after ``sensorStart``.
    stop_after : the board stops after this many packets (None: plays all).
    refuse : command names answered ``Error -1``; unknown : answered ``'...'
    is not recognized as a CLI command``.
    scene : the :class:`Scene` its packets are frames of (None: its own, from
    its start); ``first_packet`` is the first one it sent.
    phase_s : with a scene, the board writes packet ``i`` this long after the
    scene's time of it (boards on their own clocks end their frames at
    different moments of a period; 0: every board of the scene at once).
    """

    def __init__(self, packets, *, frame_period_s=FRAME_PERIOD_S, cli=True, garbled_first=True,
                 start_delay_s=0.0, stop_after=None, refuse=(), unknown=(), scene=None,
                 phase_s=0.0):
        self.packets = list(packets)
        self.scene = scene
        self.phase_s = float(phase_s)
        self.first_packet = 0
        self.frame_period_s = frame_period_s
        self.garbled_first = garbled_first
        self.start_delay_s = start_delay_s
        self.stop_after = stop_after
        self.refuse, self.unknown = set(refuse), set(unknown)
        self.commands: list[str] = []
        self.write_times: list[float] = []      # host time each packet's last byte went out
        self.done = threading.Event()           # every packet it will send is sent
        self._stop = threading.Event()
        self._started = threading.Event()
        self._running = False
        self._fds = []
        self.data_port, self._data = self._pair()
        self.cli_port = None
        threads = [threading.Thread(target=self._play, daemon=True)]
        if cli:
            self.cli_port, self._cli = self._pair()
            threads.append(threading.Thread(target=self._serve, daemon=True))
        else:
            self._started.set()
        self._threads = threads
        for t in threads:
            t.start()

    def _pair(self):
        master, slave = os.openpty()
        tty.setraw(slave)                  # no echo, no line editing, bytes as they are
        tty.setraw(master)
        self._fds += [master, slave]       # the slave stays open: no hang-up between opens
        return os.ttyname(slave), master

    def close(self):
        self._stop.set()
        self._started.set()
        for t in self._threads:
            t.join(timeout=5)
        for fd in self._fds:
            os.close(fd)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------- CLI
    def _write(self, fd, data: bytes) -> float | None:
        """Write all of ``data``; returns the host time just before the write
        that took its last byte (after it, this thread may wait for the GIL:
        a stamp taken then would be late)."""
        view = memoryview(data)
        when = None
        while view and not self._stop.is_set():
            _, ready, _ = select.select([], [fd], [], 0.1)
            if ready:
                when = time.monotonic()
                view = view[os.write(fd, view):]
        return when

    def _serve(self):
        line = bytearray()
        first = True
        while not self._stop.is_set():
            ready, _, _ = select.select([self._cli], [], [], 0.1)
            if not ready:
                continue
            line += os.read(self._cli, 1024)
            while b"\n" in line:
                raw, _, rest = bytes(line).partition(b"\n")
                line = bytearray(rest)
                text = raw.decode("ascii", "replace").strip()
                self._write(self._cli, self._answer(text, first))
                first = False

    def _answer(self, text: str, first: bool) -> bytes:
        if first and self.garbled_first:           # power-up: the line's start is lost
            garbled = "\x7f\x00" + text[3:]
            return (f"{garbled}\r\n'{garbled}' is not recognized as a CLI command\r\n"
                    ).encode("latin-1") + PROMPT
        self.commands.append(text)
        command = text.split()[0] if text else ""
        if command in self.unknown:
            reply = f"'{command}' is not recognized as a CLI command"
        elif command in self.refuse:
            reply = "Error -1"
        elif command == "sensorStop":
            reply = "Done" if self._running else "Ignored: Sensor is already stopped"
            self._running = False
        elif command == "sensorStart":
            self._running = True
            self._started.set()
            reply = "Done"
        else:
            reply = "Done"
        return f"{text}\r\n{reply}\r\n".encode() + PROMPT

    # ------------------------------------------------------------- data
    def _play(self):
        self._started.wait()
        if self._stop.wait(self.start_delay_s):
            return
        n = len(self.packets) if self.stop_after is None else min(self.stop_after,
                                                                   len(self.packets))
        now = start = time.monotonic()
        if self.scene is not None:
            # The packets of the scene's past are lost (the board did not run then).
            start = self.scene.begin(now) + self.phase_s
            self.first_packet = min(n, max(0, math.ceil((now - start) / self.frame_period_s)))
        for i in range(self.first_packet, n):
            wait = start + i * self.frame_period_s - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            if self._stop.is_set():
                return
            when = self._write(self._data, self.packets[i])
            if when is None:                       # stopped while writing
                return
            self.write_times.append(when)
        self.done.set()


def board_packets(n_frames: int, *, node: str = "S1", demo: str = "oob", seed: int = 1,
                  first_frame: int = 1, trajectory: str = "straight") -> list[bytes]:
    """One packet per frame of a simulated node's point cloud (network C,
    a straight walk unless ``trajectory``), lifted to 3D at the node's
    sample mounting."""
    rec = simulated(n_frames, seed=seed, trajectory=trajectory)
    det = rec.nodes[node].point_cloud
    height, tilt = MOUNTS[node]
    xyz, dop = lift(det, height, tilt, seed)
    packets = []
    for f in range(n_frames):
        rows = det.frame == f
        if demo == "oob":
            packets.append(encode_oob_frame(f + first_frame, xyz[rows], dop[rows],
                                            det.snr_db[rows], np.full(rows.sum(), 45.0)))
        else:
            r = np.linalg.norm(xyz[rows], axis=1)
            az = np.arctan2(xyz[rows, 0], xyz[rows, 1])
            el = np.arcsin(xyz[rows, 2] / np.maximum(r, 1e-9))
            packets.append(encode_tracking_frame(f + first_frame, r, az, el, dop[rows]))
    return packets


def damage(packets: list[bytes], seed: int = 0) -> tuple[list[bytes], set[int]]:
    """A damaged stream: some packets cut short, some with noise before them;
    returns the packets and the indices of those that cannot be read."""
    rng = np.random.default_rng(seed)
    out, lost = [], set()
    for i, p in enumerate(packets):
        kind = rng.integers(0, 8) if 0 < i < len(packets) - 1 else 7
        if kind == 0:
            out.append(p[: len(p) // 2])                   # cut short by the next packet
            lost.add(i)
        elif kind == 1:
            out.append(rng.integers(0, 256, 37, dtype=np.uint8).tobytes() + p)
        else:
            out.append(p)
    return out, lost


#: Generous bounds for a loaded 2-core machine (s).
TIMEOUT_S = 90.0


def pending_bytes(board) -> int:
    """Bytes of the board's data port not yet read by the program under test."""
    import fcntl
    import termios
    slave = os.open(board.data_port, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        return int.from_bytes(fcntl.ioctl(slave, termios.FIONREAD, b"\0" * 4), "little")
    finally:
        os.close(slave)


def wait_for(condition, what: str, timeout_s: float = TIMEOUT_S) -> None:
    """Poll ``condition()`` until true (an assertion error after ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def run_until_played(args: list[str], boards: dict, cfg: str, *, cwd) -> tuple[int, str, str]:
    """Run ``python -m mmsnap_graph ARGS`` with one ``--board NAME=CLI,DATA,CFG``
    a board until every board has played its packets and the program has read
    every byte of them, then end it with Ctrl-C (SIGINT) as a user would: its
    return code, standard output and standard error. The boards are closed
    (and the program killed if it is still running) whatever happens."""
    for name, b in boards.items():
        args = [*args, "--board", f"{name}={b.cli_port},{b.data_port},{cfg}"]
    proc = subprocess.Popen([sys.executable, "-m", "mmsnap_graph", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for b in boards.values():
            wait_for(lambda: b.done.is_set() or proc.poll() is not None, "the boards to play")
            wait_for(lambda: pending_bytes(b) == 0 or proc.poll() is not None,
                     "the program to read every byte")
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        for b in boards.values():
            b.close()
    return proc.returncode, stdout, stderr
