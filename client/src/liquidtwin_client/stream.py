"""Stream a recording into a session and collect what comes back.

Two pacings:

- ``realtime``: each stamp's samples go out when its recorded time has elapsed since the
  first stamp (wall clock). The server may supersede frames it cannot keep up with; they
  show as ``dropped_stale`` in the summary.
- ``max``: lockstep — each frame goes out as soon as the previous frame's particles came
  back; a frame whose particles do not arrive within ``frame_timeout`` counts as timed
  out and streaming goes on, unless the session's status says it is closed or failed
  (then :class:`StreamAborted`).

Per stamp the camera, mask and image samples are published before the poses sample.
"""

from __future__ import annotations

import time

from liquidtwin_proto import now_ns
from tqdm import tqdm

from .replay import Replay
from .results import ResultsWriter
from .session import SessionHandle
from .summary import StreamSummary, Tally

RATES = ("realtime", "max")
#: Session states in which no more frames will be answered.
_DEAD = ("closed", "failed")
#: After the last frame, how long to keep collecting its remaining outputs, s.
_TAIL_S = 2.0


def stream_replay(session: SessionHandle, replay: Replay, *, rate: str = "max",
                  frame_timeout: float = 30.0, writer: ResultsWriter | None = None,
                  tracking: str = "", progress: bool = True, skip: tuple = ()) -> StreamSummary:
    """Publish every stamp of ``replay`` to ``session`` and gather the outputs.

    Args:
        rate: "realtime" (paced by the recorded stamps) or "max" (lockstep).
        frame_timeout: seconds to wait for a frame's particles (``max``) and, at the end,
            for the last frame's particles (both rates).
        writer: where every received output is written (None: nowhere).
        tracking: name of the tracking mode, for the summary only.
        progress: show a progress bar on stderr (only when it is a terminal).
        skip: streams not sent (e.g. ("mask",) when the server detects liquid in the images).

    Returns:
        The run's StreamSummary.
    """
    if rate not in RATES:
        raise ValueError(f"rate must be one of {RATES}, got {rate!r}")
    if frame_timeout <= 0:
        raise ValueError(f"frame_timeout must be > 0 s, got {frame_timeout}")
    tally = Tally()
    stamps = replay.stamps
    if not stamps:
        raise ValueError(f"{replay.path}: nothing to stream (no pose, camera or image samples)")
    bar = tqdm(total=len(replay.frames), unit="frame", desc=f"stream {session.session_id}",
               disable=None if progress else True, leave=False)

    def take(out) -> None:
        tally.add(out)
        if writer is not None:
            writer.write(out)
        if out.stream == "particles":
            bar.set_postfix(answered=len(tally.answered_ns), refresh=False)

    def drain_until(done, deadline: float) -> bool:
        """Take outputs until ``done()`` or the monotonic ``deadline``; returns done()."""
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            out = session.next_output(timeout=min(left, 0.2))
            if out is not None:
                take(out)
        return True

    start = time.monotonic()
    stamp0 = stamps[0].stamp_ns
    for frame in stamps:
        if rate == "realtime":
            drain_until(lambda: False, start + (frame.stamp_ns - stamp0) * 1e-9)
        for sample in frame.samples:
            if sample.stream in skip:
                continue
            if sample.stream == "poses":
                tally.sent(frame.stamp_ns, now_ns())
            session.publish_raw(sample.stream, sample.payload, sample.stamp_ns)
        if frame.has_poses:
            bar.update(1)
            if rate == "max":
                s = frame.stamp_ns
                if not drain_until(lambda: tally.is_answered(s),
                                   time.monotonic() + frame_timeout):
                    tally.timed_out += 1
                    _check_alive(session)
        while (out := session.next_output(timeout=0)) is not None:
            take(out)
    last = replay.frames[-1].stamp_ns if replay.frames else None
    if last is not None:
        if rate == "realtime":  # in lockstep the last frame was already awaited
            drain_until(lambda: tally.is_answered(last), time.monotonic() + frame_timeout)
        drain_until(lambda: tally.has(last, "metrics") and tally.has(last, "volumes"),
                    time.monotonic() + _TAIL_S)
    wall = time.monotonic() - start
    while (out := session.next_output(timeout=0)) is not None:
        take(out)
    bar.close()
    return tally.summary(session.session_id, rate, tracking,
                         lost_outputs=session.dropped_outputs + session.bad_outputs,
                         wall_s=wall)



class StreamAborted(RuntimeError):
    """The session stopped answering for good (closed or failed on the server)."""


def _check_alive(session: SessionHandle) -> None:
    """After a frame timed out: raise StreamAborted if the session is closed or failed
    (ServerError / TimeoutError when the server no longer knows it or is gone)."""
    state = session.status(timeout=5.0).state
    if state in _DEAD:
        raise StreamAborted(f"session {session.session_id!r} is {state} on the server; "
                            "see the server log")
