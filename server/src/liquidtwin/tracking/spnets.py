"""SPNets + perception tracker (thesis §8.4, SPEC §4.4): SOLVEPERCEPTION inside the PBF inner loop.

The thesis treats the perception correction as a constraint like pressure or cohesion: in
every solver iteration of every step, ΔP^R (:func:`.perception.solve_perception`) is added to
the other position corrections, and the velocity follows from the corrected positions.

Here :meth:`SPNetsPerception.correct` stores what that needs from the latest observation (the
mask, the camera, the observed distance field, which particles were seen) and returns no
direct correction; :meth:`SPNetsPerception.terms` gives the session a :class:`PerceptionTerm`
whose ``position_delta`` runs SOLVEPERCEPTION on the solver's current positions.

Visibility is mapped by particle label from the observation — occlusion tests are too costly
for every solver iteration — and intersected with "still in front of the camera and inside
the image". An :class:`~.base.Observation` lists particles in the session state's order, not
by label, so the term's ``acceleration`` hook (called once at the start of each step with the
whole state) translates it: the first step after an observation starts from exactly the
observed state (this tracker never moves particles itself), so ``state.ids`` names them. If
the state was changed in between, visibility falls back to "in view" alone.

Until the first observation the term does nothing, so the tracker starts as open loop. The
observation is used until the next one replaces it (steps between camera frames keep pulling
toward the latest mask).

One departure from the thesis, on by default: PBF turns every solver correction into
velocity (v = (x − x₀)/dt), and at dt = 1/120 s a pull of a millimetre per iteration launches
a particle at ~0.5 m/s toward a mask that is already a frame old. ``velocity_share`` (default
0) takes the perception's share back out of the velocity after the step, so it moves liquid
without throwing it. On the golden quick pour the thesis's share 1 scored mean IOU 0.19–0.22
against open loop's 0.245; share 0 scores 0.27–0.29. ``max_move`` 0.05 h was chosen among
0.03–0.2 h on that pour and two quick benchmark cases.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..camera import in_view
from ..sim import particle_radius
from ..sim.terms import Term
from .base import Correction, Observation, Tracker
from .perception import BlendNet, apply_field, blended_field, load_blend_net, nearest_vectors

#: Cap on a particle's perception move per solver iteration, in kernel radii h.
DEFAULT_MAX_MOVE = 0.05
#: Share of the perception moves kept as velocity (1 = the thesis).
DEFAULT_VELOCITY_SHARE = 0.0


@dataclass
class _Latest:
    """What the last observation left for the inner loop."""

    camera: object = None
    mask: torch.Tensor | None = None
    field: torch.Tensor | None = None           # (2, H, W) px, nearest observed liquid
    seen_ids: torch.Tensor | None = None        # (max id + 1,) bool, seen at the observation
    pending: tuple | None = None                # (x (N, 3), visible (N,)) in the observed state's order
    cache: tuple | None = None                  # (field (2, h, w) px, origin (2,) px) of this step
    moved: torch.Tensor | None = None           # (max id + 1, 3) m, perception moves in this step, by label


def _by_label(ids: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """(max label + 1,) bool: visible (N,) in the order of ``ids`` (N,) → indexed by label."""
    out = torch.zeros(int(ids.max()) + 1 if len(ids) else 0, dtype=torch.bool, device=visible.device)
    out[ids.to(visible.device)] = visible
    return out


@dataclass(frozen=True, eq=False)
class PerceptionTerm(Term):
    """The solver term of :class:`SPNetsPerception`: ΔP^R (m) on the sorted particles.

    ``tracker``: the owning tracker (holds the latest observation and the net); a particle
    gets a move only if its label was visible at that observation and it is still in view.
    """

    tracker: "SPNetsPerception"
    name = "perception"

    def acceleration(self, model, state):
        lat = self.tracker.latest
        lat.cache = None                        # a new step: the blended field is redrawn
        lat.moved = None
        if lat.pending is not None:
            x_ref, vis = lat.pending
            lat.pending = None
            if state.x.shape == x_ref.shape and bool(torch.equal(state.x.detach(), x_ref.detach())):
                lat.seen_ids = _by_label(state.ids, vis)
        return None

    def position_delta(self, model, x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor | None:
        t = self.tracker
        lat = t.latest
        if lat.mask is None:
            return None
        seen = in_view(lat.camera, x.detach())
        if lat.seen_ids is not None:
            known = torch.zeros_like(seen)
            inside = ids < lat.seen_ids.shape[0]
            known[inside] = lat.seen_ids.to(x.device)[ids[inside]]
            seen &= known
        if not bool(seen.any()):
            return None
        if lat.cache is None or t.refresh == "iteration":
            r = particle_radius(float(model.spacing))
            lat.cache = blended_field(x, lat.camera, seen, lat.mask, t.net, radius_m=r, observed_field=lat.field)
        d = apply_field(*lat.cache, x, lat.camera, seen, t.net.gain, max_move=t.max_move * model.h)
        if t.velocity_share < 1.0:
            if lat.moved is None:
                lat.moved = x.new_zeros(int(ids.max()) + 1, 3)
            lat.moved = lat.moved.index_add(0, ids, d)
        return d

    def velocity_delta(self, model, x, v, ids):
        t, lat = self.tracker, self.tracker.latest
        if lat.moved is None or t.velocity_share >= 1.0:
            return None
        return -(1.0 - t.velocity_share) / model.dt * lat.moved[ids]


class SPNetsPerception(Tracker):
    """SPNets with perception in the solver (module doc).

    Args:
      net: the :class:`~.perception.BlendNet` (default: the shipped weights,
        :func:`~.perception.load_blend_net`).
      max_move: cap on a particle's move per solver iteration, in kernel radii h.
      velocity_share: share of the perception moves that the step turns into velocity (the
        thesis: 1, PBF's v = (x − x₀)/dt takes all of it); the rest is taken back from the
        velocity after the step, so a pull toward a one-frame-old mask is a displacement
        rather than a launch.
      refresh: "step" (default) draws the model labels and the blended field once per PBF
        step, at its first solver iteration, and reads that field at the particles' current
        projections in the step's other iterations (a capped move is ≤ ``max_move`` h, well
        under a pixel to a few pixels, so the labels barely change within a step, at a
        quarter of the cost); "iteration" redraws them in every iteration, as the thesis.
    """

    name = "spnets_perception"

    def __init__(self, net: BlendNet | None = None, *, max_move: float = DEFAULT_MAX_MOVE,
                 velocity_share: float = DEFAULT_VELOCITY_SHARE, refresh: str = "step"):
        if not (max_move > 0):
            raise ValueError(f"max_move must be > 0 kernel radii, got {max_move}")
        if refresh not in ("step", "iteration"):
            raise ValueError(f"refresh must be 'step' or 'iteration', got {refresh!r}")
        if not 0.0 <= velocity_share <= 1.0:
            raise ValueError(f"velocity_share must be in [0, 1], got {velocity_share}")
        self.refresh, self.velocity_share = refresh, float(velocity_share)
        self.net = load_blend_net() if net is None else net
        self.max_move = float(max_move)
        self.latest = _Latest()
        self._term = PerceptionTerm(self)

    def correct(self, obs: Observation) -> Correction | None:
        mask = obs.mask.to(torch.bool)
        self.latest = _Latest()      # a fresh record: a term mid-step never sees half of one
        if not bool(mask.any()):
            return None              # no liquid seen: nothing to pull toward
        self.latest = _Latest(obs.camera, mask, nearest_vectors(mask, obs.x.dtype),
                              pending=(obs.x, obs.visible.to(torch.bool)))
        return None

    def observe_labels(self, ids: torch.Tensor) -> None:
        """Name the particles of the last observation directly: ``ids`` (N,) int64 labels of
        its rows (for callers that step a state they built the observation from themselves)."""
        lat = self.latest
        if lat.pending is not None:
            lat.seen_ids, lat.pending = _by_label(ids, lat.pending[1]), None

    def terms(self) -> tuple:
        return (self._term,)

    def state_dict(self) -> dict:
        lat = self.latest
        if lat.mask is None:
            return {}
        cam = lat.camera
        seen = lat.seen_ids if lat.seen_ids is not None else torch.zeros(0, dtype=torch.bool)
        out = {} if lat.pending is None else {"pending_x": lat.pending[0], "pending_visible": lat.pending[1]}
        intr = torch.tensor([cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy], dtype=torch.float64)
        return out | {"mask": lat.mask, "seen_ids": seen, "camera_pose": cam.pose, "camera_intrinsics": intr,
                      "camera_distortion": cam.distortion}

    def load_state_dict(self, state: dict) -> None:
        if not state:
            self.latest = _Latest()
            return
        from ..camera import Camera
        w, h, fx, fy, cx, cy = state["camera_intrinsics"].tolist()
        cam = Camera(int(w), int(h), fx, fy, cx, cy, state["camera_pose"], state["camera_distortion"])
        mask = state["mask"].to(torch.bool)
        seen = state["seen_ids"].to(torch.bool)
        pending = (state["pending_x"], state["pending_visible"].to(torch.bool)) if "pending_x" in state else None
        self.latest = _Latest(cam, mask, nearest_vectors(mask), seen if len(seen) else None, pending)
