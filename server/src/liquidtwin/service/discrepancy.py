"""The session RPCs of discrepancy discovery: ``discrepancy`` and ``load_model``.

``discrepancy`` runs :func:`liquidtwin.discrepancy.analyse` on the session's own inputs since
its last reset (read back from its MCAP log, :func:`.history.session_recording`), exactly as
``liquidtwin discrepancy`` runs it on a recording file; no report files are written on the
server — the reply carries the report and the chosen model file as JSON. ``load_model``
checks a model file and hands it to the session's engine
(:meth:`~liquidtwin.session.SessionEngine.load_extension`).
"""

from __future__ import annotations

import json

from liquidtwin_proto import DiscrepancyReply

from ..session import EngineError
from ..session.errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME

#: Most null realisations a request may ask for (each is a full rollout per candidate refit).
MAX_NULL_RUNS = 8


def parse_model(text: str):
    """The :class:`~liquidtwin.discrepancy.Extension` of a model file's JSON text; EngineError
    (BAD_REQUEST) saying why it is not one (not JSON, unknown candidate, NaN, …)."""
    from ..discrepancy import model_from_dict
    if not text.strip():
        raise EngineError(BAD_REQUEST, "model_json is empty; send a model file as `liquidtwin discrepancy` writes it")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise EngineError(BAD_REQUEST, f"model_json is not JSON: {exc}") from None
    try:
        return model_from_dict(doc)
    except (ValueError, TypeError) as exc:
        raise EngineError(BAD_REQUEST, f"model_json is not a valid model file: {exc}") from None


def model_json(ext) -> str:
    """A loaded extension as model file JSON; "" for the spec's own model (name none, no base;
    or an engine without extensions)."""
    return "" if ext is None or (ext.name == "none" and not ext.base) else json.dumps(ext.as_dict(), sort_keys=True)


def options(req):
    """:class:`~liquidtwin.discrepancy.Options` of a DiscrepancyRequest (unset fields: defaults)."""
    from ..discrepancy import Options
    kw = {}
    if req.camera:
        kw["camera"] = req.camera
    if len(req.candidates):
        kw["candidates"] = tuple(req.candidates)
    if req.HasField("null_runs"):
        if req.null_runs > MAX_NULL_RUNS:
            raise EngineError(BAD_REQUEST, f"null_runs must be at most {MAX_NULL_RUNS}, got {req.null_runs}")
        kw["null_runs"] = int(req.null_runs)
    if req.HasField("calibrate"):
        kw["calibrate"] = bool(req.calibrate)
    try:
        return Options(**kw)
    except ValueError as exc:
        raise EngineError(BAD_REQUEST, str(exc)) from None


def report_doc(report: dict) -> dict:
    """The report as report.json holds it (``_series`` → ``series``), without written files."""
    doc = {k: v for k, v in report.items() if k != "_series"}
    doc["series"] = report["_series"]
    return doc


def discrepancy_reply(header, rec, req) -> DiscrepancyReply:
    """Analyse Recording ``rec`` (the session's frames) with the request's options."""
    from ..discrepancy import analyse
    opt = options(req)
    if opt.camera is not None and opt.camera not in rec.masks:
        raise EngineError(UNKNOWN_NAME, f"the session has no masks from camera {opt.camera!r} since its last reset "
                                        f"(cameras with masks: {sorted(rec.masks)})")
    try:
        report = analyse([rec], None, options=opt)
    except ValueError as exc:           # e.g. too little liquid seen to split fitting / held-out frames
        raise EngineError(INFEASIBLE, f"discrepancy analysis: {exc}") from None
    return DiscrepancyReply(header=header, session_id=header.session_id, decision=str(report["decision"]),
                            report_json=json.dumps(report_doc(report), default=float),
                            model_json=json.dumps(report["model"], sort_keys=True))
