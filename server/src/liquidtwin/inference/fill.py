"""How full was the container at the start? (thesis §7.4.2, SPEC §3)

One hypothesis per initial fill of ``container`` — by default empty, 30, 60 and 90 % of its
capacity — each filled and settled the way a session fills its scene
(:func:`liquidtwin.session._build.build_scene` / ``scenes.fill.fill_container``), all
simulated together in one :class:`~.bank.Bank` under the recording's tracked object poses,
scored against every mask frame with the δ-likelihood. The fill the recording *states* for
``container`` is ignored (it is what is being inferred); other containers keep their stated
fills. The analysis reads the recording only.
"""

from __future__ import annotations

import time

import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..scenes.fill import fill_container
from ..session._build import SETTLE_S, build_scene
from ..session.errors import EngineError
from .bank import OFFSET_M, Bank, Hypothesis, make_tracker
from .likelihood import DELTA, FILL_BLUR_PX, FILL_RADIUS_SCALE, Posterior, check_comparison, check_radius_scale
from .run import run_bank

FRACTIONS = (0.0, 0.3, 0.6, 0.9)


def fill_name(fraction: float) -> str:
    return "empty" if fraction == 0 else f"{round(100 * fraction, 1):g} %"


def _check(rec, fractions, scale) -> tuple:
    if rec.spec is None:
        raise ValueError("the recording has no scene spec; cannot build the hypotheses")
    fr = tuple(float(f) for f in (FRACTIONS if fractions is None else fractions))
    if not fr:
        raise ValueError("give at least one fill fraction")
    if any(not (0.0 <= f <= 1.0) for f in fr):
        raise ValueError(f"fill fractions must be within 0 (empty) and 1 (full), got {fr}")
    if len(set(fr)) != len(fr):
        raise ValueError(f"fill fractions must differ, got {fr}")
    if not 0.0 < float(scale) <= 1.0:
        raise ValueError(f"scale must be in (0, 1], got {scale}")
    return fr


def _container(spec: pb.SceneSpec, container: str | None) -> str:
    containers = [o.name for o in spec.objects if o.container]
    if container is None:
        filled = [f.container for f in spec.fills if f.container in containers]
        if not (filled or containers):
            raise ValueError("the scene has no container to infer the fill of")
        return (filled or containers)[0]
    if container not in containers:
        raise KeyError(f"no container {container!r} in the scene (containers: {', '.join(containers) or 'none'})")
    return container


def fill_hypotheses(spec: pb.SceneSpec, container: str, fractions, *, scale: float = 1.0,
                    progress: bool = False) -> tuple:
    """(scene, [Hypothesis]) for each fill ``fraction`` × ``scale`` of ``container``'s capacity."""
    k_obj = [o.name for o in spec.objects].index(container)
    base_spec = pb.SceneSpec()
    base_spec.CopyFrom(spec)
    del base_spec.fills[:]
    for f in spec.fills:
        if f.container != container:
            base_spec.fills.add().CopyFrom(f)
    # Build the scene once with some liquid (the largest hypothesis, else a token amount),
    # then fill every other hypothesis with the scene's own model.
    largest = max(fractions)
    probe = base_spec.fills.add(container=container)
    probe.fraction = largest * scale if largest > 0 else 0.05
    try:
        scene = build_scene(pb.SessionSpec(scene=base_spec), progress=progress)
    except EngineError as exc:
        raise ValueError(str(exc)) from None
    others = sum(r.particles for n, r in scene.fills.items() if n != container)
    x_all, v_all = scene.state.by_id()
    x_o, v_o = x_all[:others], v_all[:others]
    capacity = scene.objects[k_obj].capacity_ml
    poses = torch.as_tensor(scene.initial_poses)
    grids = tuple(scene.model.objects)
    hyps = []
    for f in fractions:
        if f == 0:
            x, v = x_o, v_o
        elif f == largest:
            x, v = x_all, v_all
        else:
            try:
                s, _ = fill_container(scene.model, poses, k_obj, scene.objects[k_obj], volume_ml=f * scale * capacity,
                                      settle_s=SETTLE_S, progress=progress)
            except ValueError as exc:
                raise ValueError(f"cannot fill {container!r} to {fill_name(f)}: {exc}") from None
            xs, vs = s.by_id()
            x, v = torch.cat([x_o, xs.to(x_o)]), torch.cat([v_o, vs.to(v_o)])
        hyps.append(Hypothesis(fill_name(f), grids, x.detach().clone(), v.detach().clone()))
    return scene, hyps


def infer_fill(rec, *, container: str | None = None, fractions=FRACTIONS, tracking: str = "warp_field",
               progress: bool = False, scale: float = 1.0, camera: str | None = None, frames: int | None = None,
               delta: float = DELTA, slack_px: float = 0.0, blur_px: float = FILL_BLUR_PX, batched: bool = True,
               offset_m: float = OFFSET_M, radius_scale: float = FILL_RADIUS_SCALE) -> Posterior:
    """Posterior over the initial fill of ``container`` given a recording.

    Args:
      rec: a Recording-like object (``spec``, ``object_names``, ``pose_times_ns`` (T,),
        ``poses`` (T, n, 7), ``cameras``, ``camera_poses``, ``masks``).
      container: the container whose fill is unknown (default: the first filled container).
      fractions: hypotheses as fractions of its capacity, 0 = empty (None = the default four).
      tracking: "warp_field" (closed loop, as the thesis scored fills), "map_filter" or
        "open_loop"; every hypothesis gets its own tracker.
      scale: each fraction is multiplied by this (generated quick scenes hold 20 % of the
        liquid of full ones: ``generate.catalog.QUICK_FILL``).
      camera: which camera's masks to score (default: the first with masks).
      frames: only the first N pose samples (default: all).
      delta: P(pixel label agrees), SPEC §3.
      slack_px: a label agrees when the other mask has it within this many px (at 640×480,
        scaled with the image; :mod:`.likelihood`). Only with ``blur_px`` 0.
      blur_px: compare the masks smoothed with a Gaussian of this σ, px at 640×480
        (:mod:`.likelihood`; default 32). Both 0: SPEC's exact pixel agreement.
      batched: all hypotheses in one simulation (else one after another: the same physics, but
        a batch runs each hypothesis at its own place, so float rounding differs between them).
      offset_m: spacing of the batched hypotheses along world x, m.
      radius_scale: the hypotheses' particles are drawn as discs of this × their projected
        radius in px (:data:`.likelihood.FILL_RADIUS_SCALE`, why in :mod:`.likelihood`).
    Returns:
      :class:`Posterior` with names like "empty", "30 %".
    """
    start = time.perf_counter()
    make_tracker(tracking)                      # a bad mode, slack or blur fails before any simulation
    check_comparison(slack_px, blur_px)
    check_radius_scale(radius_scale)
    fr = _check(rec, fractions, scale)
    name = _container(rec.spec, container)
    scene, hyps = fill_hypotheses(rec.spec, name, fr, scale=scale, progress=progress)
    bank = Bank(scene.model, hyps, scene.occluders, tracking=tracking, offset_m=offset_m, radius_scale=radius_scale)
    info = {"container": name, "fractions": list(fr), "scale": scale, "radius_scale": float(radius_scale)}
    post = run_bank(bank, rec, scene.model.dt, camera=camera, frames=frames, delta=delta, slack_px=slack_px,
                    blur_px=blur_px, batched=batched, progress=progress, info=info)
    post.info["analysis_s"] = post.wall_s
    post.wall_s = time.perf_counter() - start
    return post
