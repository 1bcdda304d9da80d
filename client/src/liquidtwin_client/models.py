"""Discrepancy discovery from the robot side: ask a session what its model gets wrong, and
load a model extension (a model file) into it.

A model file is the small JSON object ``liquidtwin discrepancy`` writes as model.json and the
``discrepancy`` RPC returns: ``{"version": 1, "name": "drag", "params": {"c": 2.1}, "base":
{"lambda_v": 45.0}}``. The server checks it (``liquidtwin.discrepancy.model_from_dict``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

#: Discrepancy discovery simulates every candidate cause over the session's frames: minutes.
DISCREPANCY_TIMEOUT_S = 1800.0


@dataclass(frozen=True)
class Discrepancy:
    """Reply of ``discrepancy``: ``decision`` (a candidate's name, "none" or "unexplained"),
    ``report`` (dict: the ARCHITECTURE.md "Discrepancy report", as report.json holds it) and
    ``model`` (dict: the chosen extension as a model file, what :meth:`load_model` takes)."""

    decision: str
    report: dict
    model: dict

    @property
    def gains(self) -> dict:
        """{candidate: mean held-out gain (coarse-loss units)} from the report."""
        return {c["name"]: c["heldout_gain"]["mean"] for c in self.report.get("candidates", [])}


def model_text(model) -> str:
    """JSON text of a model file given as a dict, an object with ``as_dict()`` (an
    ``Extension``), a JSON string, or a path to a model file. ValueError when it is none of
    these or holds a NaN/infinite number (the server checks the rest)."""
    if hasattr(model, "as_dict"):
        model = model.as_dict()
    if isinstance(model, (str, PathLike)) and not (isinstance(model, str) and model.lstrip().startswith("{")):
        path = Path(model)
        if not path.is_file():
            raise ValueError(f"model file {str(path)!r} does not exist")
        model = path.read_text()
    if isinstance(model, str):
        try:
            model = json.loads(model)
        except json.JSONDecodeError as exc:
            raise ValueError(f"not a JSON model file: {exc}") from None
    if not isinstance(model, dict):
        raise ValueError(f"a model is a dict, an Extension, JSON text or a model file path, got {type(model).__name__}")
    try:
        return json.dumps(model, allow_nan=False, sort_keys=True)
    except ValueError:
        bad = [k for k, v in {**model.get("params", {}), **model.get("base", {})}.items()
               if isinstance(v, float) and not math.isfinite(v)]
        raise ValueError(f"model parameters {bad} are NaN or infinite") from None


def discrepancy_result(reply) -> Discrepancy:
    """A :class:`Discrepancy` from a DiscrepancyReply."""
    return Discrepancy(reply.decision, json.loads(reply.report_json), json.loads(reply.model_json))
