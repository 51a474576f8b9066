"""Fixtures for the ensemble labeler's tests: loopback LLM servers and a clock that never waits."""

from __future__ import annotations

import pytest
from vdb_labeler_ensemble.testing import FakeClock, LoopbackLLM, Responder


@pytest.fixture
def loopback():
    """Start servers with ``loopback(responder, keys=…)``; all are stopped after the test."""
    servers: list[LoopbackLLM] = []

    def start(responder: Responder, keys: dict[str, str] | None = None) -> LoopbackLLM:
        server = LoopbackLLM(responder, keys).start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()


@pytest.fixture
def fake_clock() -> FakeClock:
    return FakeClock()
