"""Pour to a volume with a PD loop on the target container's volume (thesis ch. 5.1.4).

The thesis tilts the source to 75° at full speed, then sets the wrist's angular velocity
from the volume error e = target − poured with a PD law (its integral gain is 0: pouring
cannot be undone, so an integral only pushes harder) and, once the target is reached,
turns the source upright again. Here::

    rate = clip(gain · (e − lead_s · ė_flow), −max_rate, max_rate)
    angle ← clip(angle + rate · Δt, 0, max_angle)

with ė_flow the measured flow (ml/s, low-pass filtered over ``flow_filter_s``): the source
tilts at full speed while much remains (the saturated P term does the thesis's pre-tilt,
but stops as soon as liquid flows, whatever the angle), and tilts back when liquid flows
faster than ``remaining / lead_s``, so the flow dies out as the target nears. Done when
poured + drain ≥ target − ``tolerance_ml``, drain being what will still flow while the source
turns back to the angle where flow began (flow × (angle − onset) / max_rate / 2, the flow
falling linearly to zero); then the source returns upright at ``max_rate``. Without the drain
term a slow arm (low max_rate) overshoots by the liquid that leaves on its way back.

Defaults scale with the task (``gain = 2·max_rate / target``: full rate until half is
poured); :func:`thesis_gains` gives the thesis's fixed gains (P = 0.01π/180 rad/s per ml,
D = 0.2π/180 rad per ml, i.e. lead 20 s) for 100–300 ml pours over 25 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

THESIS_START_ANGLE = math.radians(75.0)


def thesis_gains() -> dict:
    """{gain (rad/s per ml), lead_s (s)} of the thesis's PD controller."""
    return {"gain": 0.01 * math.pi / 180.0, "lead_s": 20.0}


@dataclass
class PourPID:
    """PD pour-to-volume controller (module doc); one instance per task.

    Attributes:
      target_ml: volume to move into the target, ml (> 0).
      max_angle: tilt limit from upright, rad, in (0, π]. max_rate: rate limit, rad/s (> 0).
      angle: commanded tilt now, rad (start: the source's measured tilt).
      gain: rad/s per ml of error (None: 2·max_rate / target_ml). lead_s: derivative time, s.
      tolerance_ml: done when poured ≥ target − tolerance (None: 2 % of the target).
      flow_filter_s: time constant of the flow estimate's low-pass filter, s.
    """

    target_ml: float
    max_angle: float
    max_rate: float
    angle: float = 0.0
    gain: float | None = None
    lead_s: float = 0.5
    tolerance_ml: float | None = None
    flow_filter_s: float = 0.1
    rate: float = 0.0
    done: bool = False
    flow: float = 0.0
    onset: float = -1.0             # commanded angle where flow was first seen, rad (−1: not yet)
    _last: tuple = field(default=(), repr=False)   # (t s, poured ml) of the previous update

    def __post_init__(self):
        for k in ("target_ml", "max_angle", "max_rate", "lead_s", "flow_filter_s"):
            v = float(getattr(self, k))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"pour controller: {k} must be a positive number, got {v}")
        if self.max_angle > math.pi:
            raise ValueError(f"pour controller: max_angle must be at most π rad (upside down), got {self.max_angle}")
        if self.gain is None:
            self.gain = 2.0 * self.max_rate / self.target_ml
        if self.tolerance_ml is None:
            self.tolerance_ml = 0.02 * self.target_ml
        if not (math.isfinite(self.gain) and self.gain > 0 and 0 <= self.tolerance_ml < self.target_ml):
            raise ValueError(f"pour controller: need gain > 0 and 0 <= tolerance < target, "
                             f"got {self.gain}, {self.tolerance_ml}")
        self.angle = min(max(float(self.angle), 0.0), self.max_angle)

    def update(self, t: float, poured_ml: float) -> tuple[float, float, bool]:
        """Advance the controller to time ``t`` (s) with the volume poured so far (ml).
        Returns (commanded angle rad, commanded rate rad/s, done)."""
        if not (math.isfinite(t) and math.isfinite(poured_ml)):
            raise ValueError(f"pour controller: time and volume must be finite, got {t}, {poured_ml}")
        dt = 0.0
        if self._last:
            dt = max(0.0, t - self._last[0])
            if dt > 0:
                a = dt / (self.flow_filter_s + dt)
                self.flow += a * ((poured_ml - self._last[1]) / dt - self.flow)
        self._last = (t, poured_ml)
        error = self.target_ml - poured_ml
        if self.onset < 0 and self.flow > 0.05 * self.target_ml:     # flowing: > 5 % of the target per s
            self.onset = self.angle
        drain = 0.5 * self.flow * max(self.angle - self.onset, 0.0) / self.max_rate if self.onset >= 0 else 0.0
        if not self.done and error - max(drain, 0.0) <= self.tolerance_ml:
            self.done = True
        if self.done:
            rate = -self.max_rate
        else:
            rate = self.gain * (error - self.lead_s * self.flow)
            rate = min(max(rate, -self.max_rate), self.max_rate)
        # The rate acts from now to the next update; the angle integrates the last rate.
        self.angle = min(max(self.angle + self.rate * dt, 0.0), self.max_angle)
        if (self.angle <= 0.0 and rate < 0) or (self.angle >= self.max_angle and rate > 0):
            rate = 0.0
        self.rate = rate
        return self.angle, self.rate, self.done

    def state_dict(self) -> dict:
        """Plain numbers only (checkpoints)."""
        d = {k: float(getattr(self, k)) for k in ("target_ml", "max_angle", "max_rate", "angle", "gain", "lead_s",
                                                   "tolerance_ml", "flow_filter_s", "rate", "flow", "onset")}
        d["done"] = bool(self.done)
        d["has_last"] = bool(self._last)
        d["last_t"], d["last_ml"] = (float(self._last[0]), float(self._last[1])) if self._last else (0.0, 0.0)
        return d

    @classmethod
    def from_state_dict(cls, d: dict) -> "PourPID":
        pid = cls(**{k: d[k] for k in ("target_ml", "max_angle", "max_rate", "angle", "gain", "lead_s",
                                       "tolerance_ml", "flow_filter_s", "rate", "flow", "onset")},
                  done=bool(d["done"]))
        pid._last = (d["last_t"], d["last_ml"]) if d["has_last"] else ()
        return pid
