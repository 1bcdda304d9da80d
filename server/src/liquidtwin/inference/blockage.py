"""Which leg of the pipe junction is blocked, and how much? (thesis §7.4.3, Fig. 7.7)

Five hypotheses of the junction's hidden plug (``geometry.pipe_junction``): none, left or
right leg partially blocked (the plug fills ``partial`` of the leg's height; liquid must rise
over it) or fully blocked. Each is the scene with the junction's SDF rebuilt with that plug;
all five start from the same settled fill (the recording's stated fill of its source), run
under the tracked poses and are scored per mask frame with the δ-likelihood; the
probability over time is kept. The analysis reads the recording only (the recorded spec
describes the junction without any plug).

By default the hypotheses run one after another (``batched=False``). They are the same
scene until liquid reaches a plug, and run alone they stay bit-identical until then, so
only what a plug does moves the posterior. A batch (:class:`~.bank.Bank`) runs each at its
own place, 2 m apart, where float rounding differs; the cup's chaotic stream amplifies that
within half a second, and on a "none" pipe scene the posterior of "none" had fallen to 0.03
before any liquid reached a leg (``liquidtwin evaluate blockage --seed 10 --batched yes``).
On two cores a batch is no faster (``bench/fill_inference.py``).
"""

from __future__ import annotations

import time

from liquidtwin_proto import liquidtwin_pb2 as pb

from ..geometry import build
from ..session._build import build_scene
from ..session.errors import EngineError
from .bank import OFFSET_M, Bank, Hypothesis, make_tracker
from .likelihood import DELTA, SLACK_PX, Posterior, check_comparison
from .run import run_bank

PIPE_MODEL = "pipe_junction"
#: Hypothesis name → (left, right) blocked fraction; "partial" is replaced by ``partial``.
BLOCKAGES = {"none": (0.0, 0.0), "left_partial": ("partial", 0.0), "left_full": (1.0, 0.0),
             "right_partial": (0.0, "partial"), "right_full": (0.0, 1.0)}
#: The partial plug of the hypotheses and of ``liquidtwin evaluate blockage``'s worlds: the lower
#: 30 % of the leg's height. In the pipe scene it lets 19–20 % of the liquid through the leg
#: (against 49 % unblocked; ``bench/pipe_scene.py``). A 60 % plug let only 5–7 % through, so
#: "partial" was nearly "full"; the thesis's partial plug restricted the flow so mildly that its
#: open-loop tracker once read it as no blockage (§7.4.3).
PARTIAL = 0.3


def _pipe_object(spec: pb.SceneSpec, obj: str | None) -> int:
    names = [o.name for o in spec.objects]
    if obj is None:
        pipes = [k for k, o in enumerate(spec.objects) if o.model == PIPE_MODEL]
        if not pipes:
            raise ValueError(f"the scene has no {PIPE_MODEL} object (objects: {', '.join(names)})")
        return pipes[0]
    if obj not in names:
        raise KeyError(f"no object {obj!r} in the scene (objects: {', '.join(names)})")
    k = names.index(obj)
    if spec.objects[k].model != PIPE_MODEL:
        raise ValueError(f"object {obj!r} is a {spec.objects[k].model!r}, not a {PIPE_MODEL}")
    return k


def blockage_hypotheses(spec: pb.SceneSpec, obj: str | None = None, names=tuple(BLOCKAGES), *,
                        partial: float = PARTIAL, progress: bool = False) -> tuple:
    """(scene, [Hypothesis]) for the junction blockages ``names`` (keys of BLOCKAGES)."""
    unknown = [n for n in names if n not in BLOCKAGES]
    if unknown or not names:
        raise ValueError(f"unknown blockage hypotheses {unknown}; known: {', '.join(BLOCKAGES)}")
    if not 0.0 < partial < 1.0:
        raise ValueError(f"partial must be a blocked fraction in (0, 1), got {partial}")
    k = _pipe_object(spec, obj)
    try:
        scene = build_scene(pb.SessionSpec(scene=spec), progress=progress)
    except EngineError as exc:
        raise ValueError(str(exc)) from None
    params = {key: float(v) for key, v in spec.objects[k].params.items() if key not in ("left", "right")}
    x, v = scene.state.by_id()
    hyps = []
    for name in names:
        left, right = (partial if s == "partial" else s for s in BLOCKAGES[name])
        grids = list(scene.model.objects)
        grids[k] = build(PIPE_MODEL, **params, left=float(left), right=float(right)).sdf()
        hyps.append(Hypothesis(name, tuple(grids), x.detach().clone(), v.detach().clone()))
    return scene, hyps


def infer_blockage(rec, *, obj: str | None = None, hypotheses=tuple(BLOCKAGES), tracking: str = "warp_field",
                   partial: float = PARTIAL, progress: bool = False, camera: str | None = None,
                   frames: int | None = None, delta: float = DELTA, slack_px: float = SLACK_PX,
                   blur_px: float = 0.0, batched: bool = False, offset_m: float = OFFSET_M) -> Posterior:
    """Posterior (and probability over time) over the junction's blockage given a recording.

    Args:
      rec: a Recording-like object (see :func:`~.fill.infer_fill`); its scene must hold a
        ``pipe_junction`` object (``obj``, default: the first one) and a filled source.
      hypotheses: names from BLOCKAGES (default all five).
      tracking, camera, frames, delta, slack_px, blur_px, offset_m: as in :func:`~.fill.infer_fill`
        (here the default is the 16 px slack, no blur: the setting the blockage benchmark measured).
      batched: all five in one simulation; default one after another (module doc).
      partial: blocked fraction of a partial plug (default PARTIAL).
    """
    start = time.perf_counter()
    make_tracker(tracking)                      # a bad mode, slack or blur fails before any simulation
    check_comparison(slack_px, blur_px)
    if rec.spec is None:
        raise ValueError("the recording has no scene spec; cannot build the hypotheses")
    scene, hyps = blockage_hypotheses(rec.spec, obj, tuple(hypotheses), partial=partial, progress=progress)
    bank = Bank(scene.model, hyps, scene.occluders, tracking=tracking, offset_m=offset_m)
    k = _pipe_object(rec.spec, obj)
    post = run_bank(bank, rec, scene.model.dt, camera=camera, frames=frames, delta=delta, slack_px=slack_px,
                    blur_px=blur_px, batched=batched, progress=progress, info={"object": rec.spec.objects[k].name, "partial": partial})
    post.info["analysis_s"] = post.wall_s
    post.wall_s = time.perf_counter() - start
    return post
