"""liquidtwin's Zenoh service (``liquidtwin serve``): sessions, streams, logs, checkpoints.

The behaviour is docs/service.md; the physics lives behind :class:`liquidtwin.session.SessionEngine`.
Names are imported on first use, so ``liquidtwin --help`` does not load torch or Zenoh.
"""

from importlib import import_module

_WHERE = {
    "load_checkpoint": "checkpoint", "restorable": "checkpoint", "sessions_root": "checkpoint",
    "add_serve_parser": "cli", "run_serve": "cli",
    "ConfigError": "config", "ServeConfig": "config", "zenoh_config": "config",
    "InputChecker": "inputs", "InputError": "inputs",
    "LogRecord": "log", "SessionLog": "log", "read_log": "log", "read_segment": "log", "segments": "log",
    "Server": "server", "ServedSession": "session",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f".{_WHERE[name]}", __name__), name)
