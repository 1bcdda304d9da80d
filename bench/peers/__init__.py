"""Peer simulators that ``liquidtwin bench`` runs side by side with ours.

Each peer is an independent implementation of the same Position Based Fluids
step (Macklin & Mueller 2013) written on another framework, so the bench can
print "our speed / peer speed" on the same machine and thread budget.

Peers are a bench-only extra (``pip install -r bench/requirements-peers.txt``);
the main bench must keep working without them.  A peer whose framework is not
importable raises :class:`PeerNotInstalled` (a subclass of ``ImportError``), and
:func:`try_run_peer` turns that into ``None`` for callers that just want to skip.
"""

from __future__ import annotations

import importlib
from typing import Optional

__all__ = [
    "PEERS",
    "PEER_REQUIREMENTS",
    "PeerNotInstalled",
    "peer_available",
    "run_peer",
    "try_run_peer",
]

#: peer name -> module implementing ``run(n_particles, steps, warmup) -> dict``
PEERS = {
    "taichi": "bench.peers.taichi_pbf",
}

#: where the pinned peer versions live (relative to the repository root)
PEER_REQUIREMENTS = "bench/requirements-peers.txt"


class PeerNotInstalled(ImportError):
    """The framework a peer benchmark needs is not importable."""

    def __init__(self, peer: str, package: str, cause: Optional[BaseException] = None):
        self.peer = peer
        self.package = package
        msg = (
            f"peer benchmark {peer!r} needs the {package!r} package, which is not installed; "
            f"install the bench-only extra with: pip install -r {PEER_REQUIREMENTS}"
        )
        if cause is not None:
            msg += f" (import failed: {cause})"
        super().__init__(msg, name=package)


def _module(peer: str):
    try:
        modname = PEERS[peer]
    except KeyError:
        raise ValueError(f"unknown peer {peer!r}; known peers: {sorted(PEERS)}") from None
    return importlib.import_module(modname)


def peer_available(peer: str) -> bool:
    """True when the peer's framework can be imported here."""
    return _module(peer).available()


def run_peer(peer: str, n_particles: int, steps: int = 50, warmup: int = 10) -> dict:
    """Run one peer; raises :class:`PeerNotInstalled` when its framework is missing."""
    return _module(peer).run(n_particles, steps=steps, warmup=warmup)


def try_run_peer(peer: str, n_particles: int, steps: int = 50, warmup: int = 10) -> Optional[dict]:
    """Like :func:`run_peer`, but returns ``None`` when the peer is not installed."""
    try:
        return run_peer(peer, n_particles, steps=steps, warmup=warmup)
    except PeerNotInstalled:
        return None
