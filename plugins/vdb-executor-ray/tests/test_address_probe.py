"""An unreachable --address is one line at once, before Ray would retry it for minutes."""

from __future__ import annotations

import socket
import time

import pytest
from vdb_executor_ray.executor import RayExecutor, check_reachable
from vladrivebench import ConfigError


def test_a_listening_port_is_accepted():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        check_reachable(f"127.0.0.1:{port}")
        check_reachable(f"ray://127.0.0.1:{port}")


def test_a_closed_port_is_refused_fast():
    with socket.socket() as probe:  # a port that was free a moment ago, closed again
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    started = time.perf_counter()
    with pytest.raises(ConfigError, match=f"no Ray cluster answers at 127.0.0.1:{port}"):
        RayExecutor(address=f"127.0.0.1:{port}")
    assert time.perf_counter() - started < 5


@pytest.mark.parametrize("address", ["nohost", "host:", ":80", "host:99999", "host:http"])
def test_a_malformed_address_is_refused(address):
    with pytest.raises(ConfigError, match="address must be"):
        check_reachable(address)


def test_auto_is_left_to_ray():
    check_reachable("auto")
