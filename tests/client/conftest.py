"""Fixtures of the client tests: ``fake_server`` (see client_fakes.py)."""

import pytest
from client_fakes import FakeServer


@pytest.fixture
def fake_server():
    """A FakeServer listening on a free 127.0.0.1 port, closed after the test."""
    server = FakeServer()
    yield server
    server.close()
