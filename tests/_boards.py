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

Synchronisation is by events and the board's own log of what it did
(``commands``, ``write_times``), never by sleeping in the test.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import numpy as np

from ti_encode import encode_oob_frame, encode_tracking_frame
from ti_samples import FRAME_PERIOD_S, MOUNTS, lift, simulated

PROMPT = b"mmwDemo:/>"


class EmulatedBoard:
    """One board (module docstring).

    packets : the data port's packets, one per frame, in order.
    cli : whether the board has a CLI port (False: it streams from the start).
    garbled_first : the first command after power-up comes back garbled.
    start_delay_s : the data port starts this long after ``sensorStart``.
    stop_after : the board stops after this many packets (None: plays all).
    refuse : command names answered ``Error -1``; unknown : answered ``'...'
    is not recognized as a CLI command``. go : an event the data port also
    waits for (:func:`start_together`).
    """

    def __init__(self, packets, *, frame_period_s=FRAME_PERIOD_S, cli=True, garbled_first=True,
                 start_delay_s=0.0, stop_after=None, refuse=(), unknown=(), go=None):
        self.packets = list(packets)
        self.frame_period_s = frame_period_s
        self.garbled_first = garbled_first
        self.start_delay_s = start_delay_s
        self.stop_after = stop_after
        self.refuse, self.unknown = set(refuse), set(unknown)
        self.go = go
        self.commands: list[str] = []
        self.write_times: list[float] = []      # host time after each packet's last byte
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
        if self.go is not None:
            self.go.set()
        for t in self._threads:
            t.join(timeout=5)
        for fd in self._fds:
            os.close(fd)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------- CLI
    def _write(self, fd, data: bytes):
        view = memoryview(data)
        while view and not self._stop.is_set():
            _, ready, _ = select.select([], [fd], [], 0.1)
            if ready:
                view = view[os.write(fd, view):]

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
        if self.go is not None:
            self.go.wait()
        if self._stop.wait(self.start_delay_s):
            return
        n = len(self.packets) if self.stop_after is None else min(self.stop_after,
                                                                   len(self.packets))
        start = time.monotonic()
        for i in range(n):
            wait = start + i * self.frame_period_s - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            if self._stop.is_set():
                return
            self._write(self._data, self.packets[i])
            self.write_times.append(time.monotonic())
        self.done.set()


def start_together(make_boards):
    """Boards whose data ports start together, once every one of them got
    ``sensorStart`` (their packets of one frame number are then one instant,
    as real boards' frames are): ``make_boards(go)`` makes them with
    ``go=go``; returns them."""
    go = threading.Event()
    boards = make_boards(go)

    def release():
        while not all(b._started.is_set() for b in boards.values()):
            time.sleep(0.01)
        go.set()

    threading.Thread(target=release, daemon=True).start()
    return boards


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
