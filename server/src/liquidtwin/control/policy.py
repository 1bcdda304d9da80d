"""A catching policy learned by backpropagation through SPNets (thesis §8.3.4, SPEC §7).

The policy maps an image of the particles to the catcher's velocity along x::

    160×120 image → conv(10 3×3, stride 2) → ReLU → [avg-pool] → linear 100 → ReLU → linear 1 → tanh

times :data:`~liquidtwin.control.catch.MAX_SPEED`. The image is the differentiable
projection of the thesis's §8.3.2 (:func:`liquidtwin.camera.splat`) of *every* particle into
a virtual camera that moves with the catcher (its x is the catcher's x), placed so both cups
are in view. The policy therefore sees the liquid relative to itself and nothing else.

Training (:func:`train`, as the thesis): from the states of MPC runs on the training source
motions (:func:`demonstrations`), each iteration samples one time step per motion, puts the
catcher at the demonstration's x plus Gaussian noise (σ 5 cm), rolls the policy ``rollout`` steps
through the model and sums the catching task's loss (:class:`~liquidtwin.control.catch.CatchLoss`,
with the MPC's predicted first landing while nothing falls yet),
then takes one Adam step on the policy's weights with the gradient through the whole
rollout — the images, the simulator, the catcher's motion.

One change from the thesis's layout, on by default: a 2×2 average pool after the
convolution. Without it the first linear layer has 10·59·79·100 = 4.66 M weights (9.3 MB
in half precision); with it 1.13 M (2.3 MB). ``pool=1`` is the thesis's network. A 4×4 pool
(266 k weights) was tried first and learned nothing but a constant drift: its cells are 5 cm
wide, coarser than the offsets between stream and catcher it has to tell apart. And a change in sampling: the
thesis draws the time step uniformly; here half the draws come from the steps where liquid
falls (``Demonstration.active``), because in this scene the stream lasts about a quarter of
the episode and the rest teaches only "hold still" or "go where it will land" (which the
other, uniform, draws keep teaching).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .. import _weights
from ..camera import Camera, splat
from .catch import MAX_SPEED, CatchLoss, catch_space
from .mpc import ControlError
from ..scenes.liquid_level import held
from ..sim import FluidState, step

FORMAT = "liquidtwin-catch-policy-1"
WIDTH, HEIGHT = 160, 120
#: The camera in the catcher's frame (m): 1 m in front of the scene's plane, looking at a
#: point 20 cm above the catcher's base; 30° vertical field of view (0.54 m tall, 0.71 m wide
#: at the scene's plane, 4.5 mm a pixel: both cups whenever the source is within ±30 cm).
EYE, TARGET, FOV_Y_DEG = (0.0, 0.2, 1.0), (0.0, 0.2, 0.0), 30.0
SIGMA_PX = 1.0
DEFAULT_POLICY = Path(__file__).resolve().parent.parent / "data" / "catch_policy.pt"


class PolicyError(ControlError):
    """A policy file that cannot be used (says why)."""


def observation_camera() -> Camera:
    return Camera.look_at(EYE, TARGET, width=WIDTH, height=HEIGHT, fov_y_deg=FOV_Y_DEG, name="policy")


class CatchPolicy(nn.Module):
    """The policy network (module doc). ``forward(images (B, H, W))`` → (B,) in [−1, 1].

    ``mirror``: odd under a left–right flip of the image by construction: the network's
    pre-tanh output is h(image) − h(flipped image), so a scene mirrored about the catcher
    (the stream on its other side) gets the opposite velocity. The camera is centred on the
    catcher, so this is the task's own symmetry (x → −x), built in rather than learned; the
    thesis's network learned it."""

    def __init__(self, pool: int = 2, hidden: int = 100, mirror: bool = False):
        super().__init__()
        if pool < 1 or hidden < 1:
            raise PolicyError(f"pool and hidden must be >= 1, got {pool}, {hidden}")
        self.pool_size, self.hidden_size, self.mirror = int(pool), int(hidden), bool(mirror)
        self.conv = nn.Conv2d(1, 10, 3, stride=2)
        self.pool = nn.AvgPool2d(pool) if pool > 1 else nn.Identity()
        h, w = (HEIGHT - 3) // 2 + 1, (WIDTH - 3) // 2 + 1
        self.hidden = nn.Linear(10 * (h // pool) * (w // pool), hidden)
        self.out = nn.Linear(hidden, 1)
        nn.init.zeros_(self.out.weight)      # starts by holding still (a random start drifted)
        nn.init.zeros_(self.out.bias)
        self.camera = observation_camera()

    def _head(self, images: torch.Tensor) -> torch.Tensor:
        z = self.pool(torch.relu(self.conv(images[:, None])))
        return self.out(torch.relu(self.hidden(z.flatten(1))))[:, 0]

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        h = self._head(images)
        if self.mirror:
            h = h - self._head(images.flip(-1))
        return torch.tanh(h)

    def observe(self, x: torch.Tensor, q: torch.Tensor, setup) -> torch.Tensor:
        """(H, W) image of the particles x (N, 3) m seen from the catcher at x = q[0] m
        (differentiable w.r.t. x and q)."""
        base = torch.as_tensor(setup.poses_at(0.0)[setup.index("catcher")][:3], dtype=x.dtype)
        return self.image(x, torch.stack([q[0].to(x.dtype), base[1], base[2]]))

    def image(self, x: torch.Tensor, catcher: torch.Tensor) -> torch.Tensor:
        """(H, W) image of the particles x (N, 3) m seen from a catcher whose origin is at
        ``catcher`` (3,) m, world frame (the camera moves with it)."""
        uv, _ = self.camera.project(x - catcher.to(x.dtype))
        return splat(uv, None, HEIGHT, WIDTH, sigma_px=SIGMA_PX)

    def control(self, x: torch.Tensor, q: torch.Tensor, setup) -> torch.Tensor:
        """(1,) the catcher's velocity, m/s, float64."""
        image = self.observe(x, q, setup).to(self.conv.weight.dtype)
        return (MAX_SPEED * self(image[None])).to(torch.float64)

    def control_at(self, x: torch.Tensor, catcher) -> float:
        """The catcher's velocity along x, m/s, for particles x (N, 3) and the catcher's origin
        (3,) m, world frame (a session's catch task: no setup, no gradient)."""
        with torch.no_grad():
            image = self.image(x, torch.as_tensor(np.asarray(catcher, float)[:3], dtype=x.dtype))
            return float(MAX_SPEED * self(image.to(self.conv.weight.dtype)[None])[0])


def save_policy(path, policy: CatchPolicy, meta: dict | None = None) -> Path:
    """Write the weights (half precision), the layout and ``meta`` (plain data); read with
    :func:`load_policy` (which runs them in single precision)."""
    return _weights.write(path, FORMAT, policy, {"pool": policy.pool_size, "hidden": policy.hidden_size,
                                                 "mirror": policy.mirror, **(meta or {})}, half=True)


def load_policy(path=None) -> tuple[CatchPolicy, dict]:
    """(policy in eval mode, meta) from a policy file (default: the shipped one);
    ``torch.load(weights_only=True)``."""
    path = Path(DEFAULT_POLICY if path is None else path)
    meta, state_dict = _weights.read(path, FORMAT, PolicyError, "catching policy")
    try:
        policy = CatchPolicy(int(meta["pool"]), int(meta["hidden"]), bool(meta.get("mirror", False)))
        policy.load_state_dict(state_dict)
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise PolicyError(f"{path}: policy unreadable ({e})") from e
    return policy.eval(), meta


@dataclass
class Demonstration:
    """An MPC run on one source motion: the states before each step and the catcher's x then."""

    setup: object
    states: list
    xs: np.ndarray       # (steps,) catcher x before each step, m
    aims: np.ndarray     # (steps,) the MPC's predicted first landing then, m (NaN: none)

    def active(self, model) -> np.ndarray:
        """Indices of the steps where liquid falls (the landing loss applies)."""
        if getattr(self, "_active", None) is None:
            self._active = np.array([i for i, s in enumerate(self.states) if s is not None and
                                     CatchLoss(self.setup, model, s, 0.0).landing(s) is not None], dtype=np.int64)
        return self._active


def demonstrations(setup, model, state, **mpc) -> Demonstration:
    """Run the catching MPC on ``setup`` from ``state`` and keep its states."""
    from .catch import run_catch
    r = run_catch(setup, model, state, keep_states=True, **mpc)
    x0 = float(setup.poses_at(0.0)[setup.index("catcher")][0])
    return Demonstration(setup, r.states, np.concatenate([[x0], r.xs[:-1]]), r.aims)


def place_catcher(setup, model, state, x: float):
    """``state`` with the catcher moved to x (m) and the liquid it holds moved with it. (A
    rollout that started from the demonstration's pose would sweep the catcher to x in one
    step, centimetres in 8 ms, and fling its liquid.)"""
    k = setup.index("catcher")
    dx = float(x) - float(state.poses[k, 0])
    inside = torch.as_tensor(held(model, state, k, setup.objects[k].model)[0])
    shift = torch.zeros_like(state.x)
    shift[inside, 0] = dx
    poses = state.poses.clone()
    poses[k, 0] = float(x)
    return FluidState(state.x + shift, state.v, state.ids, poses, state.t)


def rollout_loss(policy: CatchPolicy, model, demo: Demonstration, i: int, x0: float, steps: int) -> torch.Tensor:
    """Σ over ``steps`` policy-controlled steps of the catching loss, from the demonstration's
    state before step i with the catcher at x0 (differentiable w.r.t. the policy's weights)."""
    state = place_catcher(demo.setup, model, demo.states[i], x0)
    t = i * model.dt
    space = catch_space(demo.setup, t, steps, model.dt)
    loss = CatchLoss(demo.setup, model, state, x0, demo.aims[i])
    q = torch.tensor([x0], dtype=torch.float64)
    total = 0.0
    for k in range(steps):
        u = policy.control(state.x, q, demo.setup)
        q = space.positions(q, u[None], model.dt)[0]
        poses = space.base_poses[k].clone().to(state.x)
        poses[space.index] = space.to_pose(q[None])[0].to(state.x)
        state = step(model, state, poses)
        total = total + loss(state, k, q)
    return total


@dataclass
class TrainLog:
    losses: list          # mean rollout loss per iteration
    seconds: float


def train(policy: CatchPolicy, model, demos: list, *, iterations: int = 300, lr: float = 1e-4,
          rollout: int = 3, noise_m: float = 0.05, active_share: float = 0.5, per_demo: int = 4,
          seed: int = 0, progress: bool = True) -> TrainLog:
    """Train ``policy`` in place (module doc): per iteration ``per_demo`` sampled steps of
    every demonstration (each with probability ``active_share`` one where liquid falls, else
    any), the catcher at its x + N(0, ``noise_m``²), ``rollout`` steps, one Adam step."""
    from tqdm.auto import tqdm
    if iterations < 1 or rollout < 1 or not lr > 0 or not noise_m >= 0:
        raise PolicyError("iterations and rollout must be >= 1, lr > 0, noise >= 0")
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    losses = []
    t0 = time.perf_counter()
    bar = tqdm(range(iterations), desc="policy", unit="it", disable=not progress)
    for _ in bar:
        opt.zero_grad()
        total = 0.0
        for d in [d for d in demos for _ in range(per_demo)]:
            active = d.active(model)
            active = active[active < len(d.states) - rollout]
            if active.size and rng.random() < active_share:
                i = int(rng.choice(active))
            else:
                i = int(rng.integers(0, len(d.states) - rollout))
            x0 = float(d.xs[i] + rng.normal(0.0, noise_m))
            total = total + rollout_loss(policy, model, d, i, x0, rollout) / (rollout * len(demos) * per_demo)
        total.backward()
        opt.step()
        losses.append(float(total.detach()))
        bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
    return TrainLog(losses, time.perf_counter() - t0)


def parameter_count(policy: CatchPolicy) -> int:
    return sum(p.numel() for p in policy.parameters())


__all__ = ["CatchPolicy", "Demonstration", "PolicyError", "demonstrations", "load_policy", "observation_camera",
           "parameter_count", "place_catcher", "rollout_loss", "save_policy", "train"]
