"""A session engine's checkpoint round trip, as the service does it (torch.save, then
torch.load with weights_only=True into a fresh engine of the same spec)."""

from __future__ import annotations

import io

import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from liquidtwin.session import SessionEngine


def restored_copy(eng: SessionEngine, spec: pb.SceneSpec) -> SessionEngine:
    """A new open-loop engine of ``spec`` continuing from ``eng``'s checkpoint."""
    buf = io.BytesIO()
    torch.save(eng.state_dict(), buf)
    buf.seek(0)
    other = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    other.load_state_dict(torch.load(buf, weights_only=True))
    return other
