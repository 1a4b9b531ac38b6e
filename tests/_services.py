"""A real TCP service on 127.0.0.1 for the scheduler-probe tests."""

from __future__ import annotations

import socket
import threading


class TcpService:
    """Accepts connections and sends ``banner`` to each (None: never says a
    word), holding them until closed; a context manager."""

    def __init__(self, banner: bytes | None):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.banner, self.conns, self.stop = banner, [], threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        self.sock.settimeout(0.1)
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(conn)
            if self.banner is not None:
                conn.sendall(self.banner)

    def close(self):
        self.stop.set()
        self.thread.join(5)
        for c in self.conns:
            c.close()
        self.sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
