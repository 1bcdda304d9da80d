"""Settings of one ``liquidtwin serve`` process (docs/service.md).

:class:`ServeConfig` collects what the command line sets; :func:`zenoh_config` turns it into
the Zenoh configuration of the server's peer (embedded default: listen on
``tcp/127.0.0.1:7447``, multicast scouting off; ``connect``: join a router, listen on nothing).
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from liquidtwin_proto import validate_id, validate_prefix

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
DEFAULT_STATE_DIR = "./liquidtwin-state"
#: Newest mask a frame may use, s older than the frame (docs/service.md "Streams").
MASK_MAX_AGE_S = 0.1
#: A running session without a frame for this long reports state "idle", s.
IDLE_AFTER_S = 5.0
#: Masks kept pending per camera; older ones are dropped when more arrive.
MAX_PENDING_MASKS = 16
MAX_PENDING_IMAGES = 8      # RGB frames waiting for the detector, per camera (~0.3 s at 30 Hz)


class ConfigError(ValueError):
    """A setting ``liquidtwin serve`` cannot run with (the message names the option)."""


@dataclass
class ServeConfig:
    """What a server runs with.

    Attributes:
      listen: Zenoh endpoints to listen on (ignored entries when ``connect`` is set).
      connect: endpoints to connect to (a router); when set the server listens on nothing.
      prefix: key prefix of every liquidtwin key.
      device: default torch device of sessions ("cpu" or "cuda[:N]"); a spec may name its own.
      state_dir: where session logs, specs and checkpoints live.
      checkpoint_s: seconds between checkpoints of a session that changed.
      max_payload_bytes: largest accepted Zenoh payload (RPC request or input sample), bytes.
      max_sessions: most open sessions (RESOURCE_EXHAUSTED beyond).
      orphan_grace_s: seconds an orphaned session lives before it is closed.
      max_steps_per_frame: most simulation steps per frame (the clock jumps beyond).
      threads: torch CPU threads (0: torch's default).
      server_id: liveliness id of this server (a key chunk).
      detector: liquid detector model file for sessions whose masks come from RGB
        (``SessionSpec.mask_source == "rgb"``); None: the shipped model.
      solve_impacts: a session whose SceneSpec states fewer solver iterations than liquid
        falling between its containers needs (``scenes.spec.impact_iterations``) solves that
        many, for the same liquid (``solve_with``); its status and saved spec say so.
    """

    listen: list[str] = field(default_factory=lambda: [DEFAULT_LISTEN])
    connect: list[str] = field(default_factory=list)
    prefix: str = "liquidtwin"
    device: str = "cpu"
    state_dir: Path = Path(DEFAULT_STATE_DIR)
    checkpoint_s: float = 1.0
    max_payload_bytes: int = 16 * 1024 * 1024
    max_sessions: int = 8
    orphan_grace_s: float = 60.0
    max_steps_per_frame: int = 8
    threads: int = 0
    server_id: str = ""
    mask_max_age_s: float = MASK_MAX_AGE_S
    idle_after_s: float = IDLE_AFTER_S
    detector: Path | None = None
    solve_impacts: bool = False

    def __post_init__(self) -> None:
        self.state_dir = Path(self.state_dir)
        self.detector = None if self.detector is None else Path(self.detector)
        if not self.server_id:
            self.server_id = f"server-{os.getpid()}-{uuid.uuid4().hex[:6]}"
        self.check()

    def check(self) -> None:
        """Raise ConfigError for settings that cannot work."""
        try:
            validate_prefix(self.prefix)
            validate_id(self.server_id, "server id")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        for ep in [*self.listen, *self.connect]:
            if not isinstance(ep, str) or "/" not in ep or '"' in ep:
                raise ConfigError(f"endpoint {ep!r} is not a Zenoh endpoint like tcp/127.0.0.1:7447")
        if not (self.device == "cpu" or self.device.startswith("cuda")):
            raise ConfigError(f"--device must be cpu or cuda[:N], got {self.device!r}")
        if self.detector is not None and not self.detector.is_file():
            raise ConfigError(f"--detector {self.detector} is not a file")
        for name, v, lo in (("checkpoint-s", self.checkpoint_s, 0.0), ("orphan-grace-s", self.orphan_grace_s, 0.0),
                            ("max-payload-mb", self.max_payload_bytes, 1), ("max-sessions", self.max_sessions, 1),
                            ("max-steps-per-frame", self.max_steps_per_frame, 1), ("threads", self.threads, 0)):
            if not v >= lo:
                raise ConfigError(f"--{name} must be >= {lo}, got {v}")

    @property
    def endpoints(self) -> list[str]:
        """Where this server can be reached or what it joins (for the ready line)."""
        return list(self.connect) if self.connect else list(self.listen)


def _json_list(items: list[str]) -> str:
    return "[" + ", ".join(f'"{e}"' for e in items) + "]"


def zenoh_config(cfg: ServeConfig):
    """The ``zenoh.Config`` of the server's peer."""
    import zenoh

    z = zenoh.Config()
    z.insert_json5("mode", '"peer"')
    z.insert_json5("scouting/multicast/enabled", "false")
    if cfg.connect:
        z.insert_json5("connect/endpoints", _json_list(cfg.connect))
        z.insert_json5("listen/endpoints", "[]")
    else:
        z.insert_json5("listen/endpoints", _json_list(cfg.listen))
    return z
