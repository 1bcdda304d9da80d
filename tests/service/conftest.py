"""Fixtures of the service tests: real ``liquidtwin serve`` processes on free 127.0.0.1 ports
with a temporary state dir (always killed at teardown) and bare Zenoh peers (zraw.Peer)."""

from __future__ import annotations

import pytest
import torch
from zraw import Peer, ServeProc, free_port


@pytest.fixture(autouse=True, scope="session")
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def port() -> int:
    """A free TCP port on 127.0.0.1."""
    return free_port()


@pytest.fixture
def state_dir(tmp_path):
    """An empty state dir for one server."""
    return tmp_path / "state"


class _Servers:
    """Starts servers and peers; stops/kills every one of them at teardown."""

    def __init__(self, tmp):
        self.tmp, self.procs, self.peers = tmp, [], []

    def start(self, *extra: str, state_dir=None) -> ServeProc:
        proc = ServeProc(state_dir or self.tmp / "state", *extra)
        self.procs.append(proc)
        return proc

    def peer(self, server: ServeProc) -> Peer:
        p = Peer(server.endpoint)
        self.peers.append(p)
        return p

    def teardown(self):
        for p in self.peers:
            try:
                p.close()
            except Exception:  # noqa: BLE001
                pass
        for proc in self.procs:
            if proc.alive():
                proc.kill()


@pytest.fixture
def servers(tmp_path):
    s = _Servers(tmp_path)
    yield s
    s.teardown()


@pytest.fixture(scope="module")
def module_servers(tmp_path_factory):
    s = _Servers(tmp_path_factory.mktemp("serve"))
    yield s
    s.teardown()
