"""``mmsnap batch --scheduler`` is probed before Dask connects
(:mod:`mmsnap_graph.app.scheduler_probe`): real sockets on 127.0.0.1 and a
real Dask scheduler."""

from __future__ import annotations

import struct
import time

import pytest

from _services import TcpService
from mmsnap_graph.app.scheduler_probe import MAX_HANDSHAKE_BYTES, check_scheduler
from mmsnap_graph.errors import ValidationError


def test_a_real_dask_scheduler_is_accepted():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp://",
                                  host="127.0.0.1", scheduler_port=0,
                                  dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert check_scheduler(address, 5.0) == address


def test_a_plausible_handshake_length_is_accepted():
    with TcpService(struct.pack("<Q", 120) + b"x" * 120) as svc:
        assert check_scheduler(svc.address, 2.0) == svc.address


@pytest.mark.parametrize("banner, match", [
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", "not a Dask scheduler"),
    (struct.pack("<Q", MAX_HANDSHAKE_BYTES + 1), "not a Dask scheduler"),
    (struct.pack("<Q", 0), "not a Dask scheduler"),
])
def test_another_protocol_is_refused_naming_what_it_sent(banner, match):
    with TcpService(banner) as svc:
        with pytest.raises(ValidationError, match=match) as info:
            check_scheduler(svc.address, 2.0)
        assert "--scheduler" in str(info.value)


def test_a_silent_service_is_refused_within_the_time_limit():
    with TcpService(None) as svc:
        start = time.monotonic()
        with pytest.raises(ValidationError, match="no Dask scheduler answered within 0.5 s"):
            check_scheduler(svc.address, 0.5)
        assert time.monotonic() - start < 3.0


def test_a_closed_port_says_it_cannot_connect():
    with TcpService(None) as svc:
        address = svc.address
    with pytest.raises(ValidationError, match="cannot connect"):
        check_scheduler(address, 1.0)


@pytest.mark.parametrize("address, match", [
    ("tls://127.0.0.1:8786", "only tcp://"), ("ucx://127.0.0.1:8786", "only tcp://"),
    ("tcp://127.0.0.1", "expected tcp://HOST:PORT"), ("127.0.0.1:0", "expected tcp://HOST:PORT"),
    ("tcp://127.0.0.1:65536", "expected tcp://HOST:PORT"),
])
def test_addresses_that_are_not_tcp_host_port_are_refused(address, match):
    with pytest.raises(ValidationError, match=match):
        check_scheduler(address, 1.0)
