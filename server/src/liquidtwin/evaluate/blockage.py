"""``liquidtwin evaluate blockage``: which pipe leg is blocked — the thesis's Fig. 7.7 on generated data.

Five ``pipe`` recordings, one per true blockage (none, left/right × partial/full), each with
its own seed (``base_seed + index``); the world's plug is planted with the generator's
``blockage`` effect (``blockage=0.3:leg=left`` is the partial left plug: the same 30 % plug
the hypotheses use, ``--partial``; 1.0 closes the leg). Each recording is analysed blind by
:func:`liquidtwin.inference.infer_blockage` — the five hypotheses simulated one after another
(``--batched yes``: together) and scored with the δ-likelihood (SPEC §3, ``--slack`` px of slack or ``--blur``) — open loop and warp-field tracked. Scoring reads
the truth (``REC.truth.json``) only to mark the true hypothesis.

Table: per recording and tracker, the final probability of every hypothesis (truth marked
*), whether the truth ranks first, and the time until the truth first reaches ≥ 0.99 and
stays there. Results: ``results.json`` (seeds, posteriors over time), ``blockage.png``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..inference.blockage import PARTIAL
from .benchmark import generate_all, missing_from
from .cli import add_common, add_likelihood_options, likelihood_options, save_results

HELP = "pipe-junction blockage inference, 5 hypotheses, probability over time (thesis Fig. 7.7)"
TRUTHS = ("none", "left_partial", "left_full", "right_partial", "right_full")
MODES = ("open_loop", "warp_field")
SHORT = {"none": "none", "left_partial": "L-part", "left_full": "L-full", "right_partial": "R-part",
         "right_full": "R-full"}
SURE = 0.99


@dataclass(frozen=True)
class PipeCase:
    """One pipe recording with the true blockage ``truth`` (a key of inference.BLOCKAGES);
    a partial plug blocks the lower ``partial`` of its leg's height."""

    truth: str
    seed: int
    quick: bool
    partial: float = PARTIAL

    @property
    def name(self) -> str:
        plug = f"{self.partial:g}" if self.truth.endswith("partial") else ""
        return f"pipe-{self.truth}{plug}-s{self.seed}-{'q' if self.quick else 'f'}"

    def effects(self) -> list:
        if self.truth == "none":
            return []
        leg, kind = self.truth.split("_")
        return [("blockage", self.partial if kind == "partial" else 1.0, {"leg": 0.0 if leg == "left" else 1.0})]

    def as_dict(self) -> dict:
        return asdict(self) | {"name": self.name, "effects": [list(e) for e in self.effects()]}


def pipe_cases(*, quick: bool, base_seed: int = 0, truths=TRUTHS, partial: float = PARTIAL) -> list[PipeCase]:
    return [PipeCase(t, base_seed + i, quick, partial) for i, t in enumerate(truths)]


def _generate(args) -> str:
    case_d, data = args
    import torch
    torch.set_num_threads(1)
    from ..generate import generate
    case = PipeCase(case_d["truth"], case_d["seed"], case_d["quick"], case_d["partial"])
    out = Path(data) / f"{case.name}.mcap"
    generate("pipe", out, effects=case.effects(), seed=case.seed, quick=case.quick)
    out.with_suffix(".case.json").write_text(json.dumps(case.as_dict(), indent=2) + "\n")
    return str(out)


def ensure_pipes(case_list, data: Path, *, jobs: int = 1, progress: bool = True) -> list[Path]:
    """Generate the missing recordings (``jobs`` processes); their paths in order."""
    data = Path(data)
    data.mkdir(parents=True, exist_ok=True)
    paths = [data / f"{c.name}.mcap" for c in case_list]
    work = [(case_list[i].as_dict(), str(data)) for i in missing_from(paths, progress=progress)]
    generate_all(_generate, work, jobs=jobs, desc="generate pipes", progress=progress)
    return paths


def time_to_sure(times, probs, level: float = SURE) -> float | None:
    """First time (s) from which ``probs`` (T,) stays ≥ ``level`` to the end; None if never."""
    p = np.asarray(probs, float)
    below = np.nonzero(p < level)[0]
    if len(p) == 0 or (len(below) and below[-1] == len(p) - 1):
        return None
    return float(times[0 if not len(below) else below[-1] + 1])


def routing(setup, particles: np.ndarray) -> dict:
    """Where a pipe scene's liquid went, from its true ``particles`` (T, N, 3), world frame.

    Shares of the liquid that entered the inlet (inside the top 6 cm of the vertical stem at some
    step) and that end in ``left_bowl``, ``right_bowl`` (inside the cylinder of the bowl's rim)
    and ``elsewhere``. Reads the truth: for scoring and benchmarks only, never the analysis.
    """
    k = setup.index("pipe")
    pipe = setup.objects[k].model
    poses = setup.poses_at(0.0)                    # the pipe and the bowls are static
    y0 = float(poses[k][1])
    half = 0.5 * float(pipe.mesh.bounds[1][2] - pipe.mesh.bounds[0][2]) - pipe.wall     # inner half-width
    top = y0 + float(pipe.anchors["inlet"][1])
    p = particles
    stem = (np.abs(p[..., 0]) < half) & (np.abs(p[..., 2]) < half) & (p[..., 1] < top) & (p[..., 1] > top - 0.06)
    out = {"particles": int(p.shape[1]), "entered_inlet": float(stem.any(0).mean())}
    last = p[-1]
    anywhere = np.zeros(len(last), bool)
    for name in ("left_bowl", "right_bowl"):
        j = setup.index(name)
        centre = poses[j][:3]
        lo, hi = setup.objects[j].model.mesh.bounds
        inside = (np.hypot(last[:, 0] - centre[0], last[:, 2] - centre[2]) < 0.5 * float(hi[0] - lo[0])) & (
            last[:, 1] < centre[1] + float(hi[1]))
        out[name] = float(inside.mean())
        anywhere |= inside
    out["elsewhere"] = float(1.0 - anywhere.mean())
    return out


def configure(p) -> None:
    add_common(p, out="eval-blockage")
    p.add_argument("--trackers", nargs="+", default=list(MODES), choices=["open_loop", "warp_field", "map_filter"],
                   metavar="T", help="scoring modes to compare (default: open_loop warp_field)")
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="only the first N pose samples of each recording (default: all)")
    p.add_argument("--partial", type=float, default=PARTIAL, metavar="F",
                   help=f"a partial plug blocks the lower F of its leg's height, in the world and in the "
                        f"hypotheses (default: {PARTIAL:g})")
    add_likelihood_options(p, batched="no")


def run(args) -> int:
    from tqdm import tqdm
    from ..inference import infer_blockage
    from ..recordings import read_recording
    delta, slack, blur = likelihood_options(args)
    if not 0.0 < args.partial < 1.0:
        raise SystemExit(f"--partial must be a blocked fraction in (0, 1), got {args.partial:g}")
    case_list = pipe_cases(quick=args.quick, base_seed=args.seed, partial=args.partial)
    paths = ensure_pipes(case_list, args.data, jobs=args.jobs, progress=not args.no_progress)
    results = []
    for case, path in tqdm(list(zip(case_list, paths)), desc="infer", unit="rec", disable=args.no_progress):
        rec = read_recording(path, images=False)
        row = {"case": case.as_dict(), "recording": str(path), "modes": {}}
        for mode in args.trackers:
            post = infer_blockage(rec, tracking=mode, frames=args.frames, delta=delta, slack_px=slack, blur_px=blur,
                                  batched=args.batched == "yes", partial=args.partial)
            k = post.names.index(case.truth)
            row["modes"][mode] = post.as_dict() | {
                "correct": post.best == case.truth, "p_truth": float(post.probability[k]),
                "time_to_sure_s": time_to_sure(post.times_s, post.probability_over_time[:, k])}
        row["planted"] = json.loads(path.with_suffix(".truth.json").read_text())["effect"]     # after the analyses
        results.append(row)
        _save(args, {"kind": "blockage", "partial": True, "cases": results})        # survives an interruption
    text = format_table(results, args.trackers, args.quick, delta, slack, args.partial, blur)
    print(text)
    doc = {"kind": "blockage", "quick": bool(args.quick), "base_seed": args.seed, "partial_plug": args.partial,
           "delta": delta, "slack_px": slack, "blur_px": blur,
           "batched": args.batched == "yes",
           "frames": args.frames, "trackers": list(args.trackers), "table_text": text, "cases": results}
    right = {m: sum(r["modes"][m]["correct"] for r in results) for m in args.trackers}
    best = max(right, key=right.get)
    doc["headline"] = {"name": f"pipe scenes with the true blockage ranked first ({best})", "value": right[best],
                       "unit": f"of {len(results)}"}
    out = _save(args, doc)
    _plot(out, results, args.trackers)
    return 0


def _save(args, doc: dict) -> Path:
    return save_results(args.out, doc)


def format_table(results, modes, quick: bool, delta: float, slack: float, partial: float = PARTIAL,
                 blur: float = 0.0) -> str:
    lines = []
    for mode in modes:
        lines.append(f"[{mode}]  final probability per hypothesis (* = truth)")
        lines.append("truth".ljust(15) + "".join(SHORT[n].rjust(9) for n in TRUTHS) + "  correct  t(p>=0.99)")
        ok = 0
        for r in results:
            m = r["modes"][mode]
            cells = []
            for n, p in zip(m["names"], m["probability"]):
                cells.append((f"{p:.3f}" + ("*" if n == r["case"]["truth"] else " ")).rjust(9))
            ok += bool(m["correct"])
            t = m["time_to_sure_s"]
            lines.append(r["case"]["truth"].ljust(15) + "".join(cells) + ("yes" if m["correct"] else "no").rjust(9)
                         + ("never" if t is None else f"{t:.2f} s").rjust(12))
        lines.append(f"correct {ok}/{len(results)}")
    lines.append(f"{'quick' if quick else 'full'} pipe scenes, partial plug {partial:g} of the leg, delta = {delta}, "
                 f"slack {slack:g} px, blur {blur:g} px at 640x480; "
                 f"t(p>=0.99): session time from which the truth keeps >= 0.99")
    return "\n".join(lines)


def _plot(out: Path, results, modes) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(results), len(modes), figsize=(5 * len(modes), 2.2 * len(results)), squeeze=False)
    for i, r in enumerate(results):
        for j, mode in enumerate(modes):
            m, ax = r["modes"][mode], axes[i, j]
            over = np.asarray(m["probability_over_time"])
            for k, n in enumerate(m["names"]):
                ax.plot(m["times_s"], over[:, k] if len(over) else [], label=SHORT[n],
                        lw=2.5 if n == r["case"]["truth"] else 1.0)
            ax.set_ylim(-0.02, 1.02)
            ax.set_title(f"truth {r['case']['truth']} — {mode}", fontsize=9)
            ax.set_ylabel("P")
    axes[0, 0].legend(fontsize=7, ncols=5)
    for ax in axes[-1]:
        ax.set_xlabel("session time, s")
    fig.tight_layout()
    fig.savefig(out / "blockage.png", dpi=90)
    plt.close(fig)
