"""``liquidtwin evaluate perception``: liquid detection from RGB, thesis Fig. 4.13 layout.

Trains each detector of the grid (FCNs first; a multi-frame or recurrent network starts
its input block from the trained FCN of the same input, as in the thesis) on the generated
training pours (perception.data: cup
and bottle into bowl, fruit bowl, dog dish) and scores it on those and on the test pours
with containers never seen in training (mug into pan): area under the precision–recall
curve with 0, 1, 2 and 4 px slack (at the network's 160×120), plus the optical-flow
baseline (§4.5.3). Tables: per network kind, rows RGB / grey, columns no flow / early /
late fusion, each cell train / test AUC (0 px slack), and a flow-only row; then every
network and the baseline ranked by test AUC. Figures: PR curves of the best network per
kind and the baseline; example detections on a test frame.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

HELP = "liquid detection from RGB: FCN / MF-FCN / LSTM-FCN × input types vs the optical-flow baseline (thesis Fig. 4.13)"
SLACKS = (0, 1, 2, 4)
INPUT_GRID = [("rgb", "early"), ("grey", "early"), ("flow", "early"), ("rgb_flow", "early"),
              ("grey_flow", "early"), ("rgb_flow", "late"), ("grey_flow", "late")]
QUICK_GRID = [("fcn", "grey_flow", "early"), ("mf_fcn", "grey_flow", "early"), ("lstm_fcn", "grey_flow", "early"),
              ("lstm_fcn", "rgb", "early")]


def configure(p) -> None:
    from ..perception.inputs import AUGMENT_HELP
    p.add_argument("--data", type=Path, default=Path("eval-data/perception"), metavar="DIR",
                   help="perception dataset (generated when missing; default: %(default)s)")
    p.add_argument("--out", type=Path, default=Path("eval-perception"), metavar="DIR",
                   help="where the JSON, PNG figures and trained models go (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help=f"4 networks ({', '.join('/'.join(g) for g in QUICK_GRID)}) instead of the full "
                        "grid (every kind × 7 input types), and a smaller dataset when one is generated")
    p.add_argument("--models", default=None, metavar="KIND/INPUT/FUSION[,…]",
                   help="train exactly these, e.g. lstm_fcn/grey_flow/early,fcn/rgb/early")
    p.add_argument("--train-seqs", type=int, default=None, help="training pours when generating (default 12, quick 8)")
    p.add_argument("--test-seqs", type=int, default=None, help="test pours when generating (default 4, quick 3)")
    p.add_argument("--crop-iterations", type=int, default=300, help="pre-training steps on crops (default: %(default)s)")
    p.add_argument("--full-iterations", type=int, default=150, help="steps on full frames (default: %(default)s)")
    p.add_argument("--select-every", type=int, default=0, metavar="N",
                   help="choose each network's training length on held-out pours: score it on the dataset's "
                        "calibration split every N steps and keep the best weights (0: keep the last; "
                        "default: %(default)s). The test pours are scored at the same steps for the record "
                        "(selection.png) but never choose")
    p.add_argument("--augment", default="", metavar="flip,colour",
                   help=AUGMENT_HELP)
    p.add_argument("--seed", type=int, default=0, help="dataset and training seed (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=2, help="networks trained in parallel (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def _grid(args) -> list[tuple[str, str, str]]:
    from ..perception import FUSIONS, INPUTS, KINDS
    if args.models:
        grid = [tuple(m.strip().split("/")) for m in args.models.split(",") if m.strip()]
        for g in grid:
            if len(g) != 3 or g[0] not in KINDS or g[1] not in INPUTS or g[2] not in FUSIONS:
                raise SystemExit(f"--models takes KIND/INPUT/FUSION with KIND in {KINDS}, INPUT in "
                                 f"{sorted(INPUTS)}, FUSION in {FUSIONS}; got {'/'.join(g)!r}")
        return grid
    if args.quick:
        return list(QUICK_GRID)
    return [(k, i, f) for k in KINDS for i, f in INPUT_GRID]


def scores_auc(scores: list[np.ndarray], clips) -> dict:
    """AUC per slack over a list of clips (all frames pooled)."""
    from ..perception import auc
    s = np.concatenate(scores)
    y = np.concatenate([c.masks for c in clips])
    return {str(k): auc(s, y, k) for k in SLACKS}


def _train_one(work) -> dict:
    import torch
    torch.set_num_threads(1)
    from ..perception import parameter_count, save_model
    from ..perception.data import SIZE, load_split
    from ..perception.train import TrainConfig, detect, encode_clips, train
    from ..perception import load_model
    (kind, input_type, fusion), data, out, crop_it, full_it, seed, select_every, augment = work
    train_clips, test_clips = load_split(data, "train"), load_split(data, "test")
    cfg = TrainConfig(kind=kind, input_type=input_type, fusion=fusion, crop_iterations=crop_it,
                      full_iterations=full_it, seed=seed, select_every=select_every, augment=augment)
    init = Path(out) / "models" / f"fcn-{input_type}-{fusion}.pt"
    init = init if kind != "fcn" and init.is_file() else None
    net, info = train(train_clips, cfg, progress=False, init=None if init is None else load_model(init)[0],
                      select_on=load_split(data, "calib") if select_every else None, watch=test_clips)
    res = {"kind": kind, "input_type": input_type, "fusion": fusion, "parameters": parameter_count(net),
           "init": None if init is None else init.name,
           "train_wall_s": info["wall_s"], "final_loss": float(np.mean(info["loss_history"][-20:]))}
    if "selected_step" in info:
        res.update(selected_step=info["selected_step"], checkpoints=info["checkpoints"])
    for split, clips in (("train", train_clips), ("test", test_clips)):
        probs = [detect(net, x) for x in encode_clips(clips, input_type)]
        res[split] = scores_auc(probs, clips)
        if split == "test":
            np.save(Path(out) / "models" / f"{kind}-{input_type}-{fusion}.test0.npy", probs[0].astype(np.float16))
    save_model(Path(out) / "models" / f"{kind}-{input_type}-{fusion}.pt", net,
               {"size": list(SIZE), "trained": info["config"], "dataset": str(data), "test_auc": res["test"],
                "selected_step": info.get("selected_step")})
    return res


def clips_baseline_auc(clips) -> dict:
    """AUC per slack of the optical-flow baseline (§4.5.3) over loaded clips."""
    from ..perception import baseline_scores
    return scores_auc([baseline_scores(c.frames) for c in clips], clips)


def baseline_auc(data, splits=("train", "test")) -> dict:
    """{split: AUC per slack} of the optical-flow baseline on a dataset's splits (splits with
    no pours left out)."""
    from ..perception.data import load_split
    res = {}
    for split in splits:
        clips = load_split(data, split)
        if clips:
            res[split] = clips_baseline_auc(clips)
    return res


def run(args) -> int:
    from tqdm.auto import tqdm

    from ..perception.data import load_split, make_dataset
    from .cli import save_results
    from ..procs import map_jobs
    from ..perception.inputs import parse_augment
    grid = _grid(args)
    try:
        augment = parse_augment(args.augment)
    except ValueError as e:
        raise SystemExit(f"--augment: {e}")
    if args.select_every < 0:
        raise SystemExit(f"--select-every takes N >= 0 steps, got {args.select_every}")
    if not (args.data / "dataset.json").is_file():
        n_train = args.train_seqs or (8 if args.quick else 12)
        n_test = args.test_seqs or (3 if args.quick else 4)
        n_calib = 3 if args.select_every else 0
        print(f"generating the perception dataset in {args.data} ({n_train} train + {n_test} test + {n_calib} "
              "calibration pours)")
        make_dataset(args.data, train=n_train, test=n_test, calib=n_calib, seed=args.seed,
                     progress=not args.no_progress)
    if args.select_every and not load_split(args.data, "calib"):
        raise SystemExit(f"--select-every chooses on the dataset's calibration pours and {args.data} has none; "
                         f"add them with `liquidtwin perception data --out {args.data} --calib 3 --seed "
                         f"{json.loads((args.data / 'dataset.json').read_text())['seed']}`")
    (args.out / "models").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    base = baseline_auc(args.data)
    # FCNs first: the multi-frame and recurrent networks start from the FCN of their input (thesis)
    results = []
    bar = tqdm(total=len(grid), desc="networks", unit="net", disable=args.no_progress)
    for phase in ([g for g in grid if g[0] == "fcn"], [g for g in grid if g[0] != "fcn"]):
        work = [(g, args.data, args.out, args.crop_iterations, args.full_iterations, args.seed, args.select_every,
                 augment) for g in phase]
        for r in map_jobs(_train_one, work, args.jobs):
            results.append(r)
            bar.update()
    bar.close()
    best = max(results, key=lambda r: r["test"]["0"])
    doc = {"kind": "perception", "quick": args.quick, "seed": args.seed, "data": str(args.data),
           "slacks": list(SLACKS), "iterations": {"crop": args.crop_iterations, "full": args.full_iterations},
           "select_every": args.select_every, "augment": augment, "wall_s": time.perf_counter() - t0, "baseline": base, "results": results,
           "headline": {"name": f"best test AUC (0 px slack): {best['kind']}/{best['input_type']}/{best['fusion']}",
                        "value": best["test"]["0"], "unit": "AUC"}}
    out = save_results(args.out, doc)
    _print(results, base)
    print(f"\n{doc['wall_s']:.0f} s. Results in {out}")
    _plot(out, results, base, args.data)
    return 0


def _print(results: list[dict], base: dict) -> None:
    from ..perception import KINDS
    cell = {(r["kind"], r["input_type"], r["fusion"]): r for r in results}
    fmt = lambda r: "      –      " if r is None else f"{100 * r['train']['0']:5.1f} / {100 * r['test']['0']:4.1f}"
    for kind in KINDS:
        if not any(k == kind for k, _, _ in cell):
            continue
        print(f"\n{kind}: AUC % (0 px slack), train / unseen-container test")
        print(f"{'':>8}{'no flow':>15}{'early fusion':>15}{'late fusion':>15}")
        for img in ("rgb", "grey"):
            row = [cell.get((kind, img, "early")), cell.get((kind, img + "_flow", "early")),
                   cell.get((kind, img + "_flow", "late"))]
            print(f"{img:>8}" + "".join(f"{fmt(r):>15}" for r in row))
        print(f"{'flow':>8}{fmt(cell.get((kind, 'flow', 'early'))):>15}")
    chosen = any("selected_step" in r for r in results)
    print(f"\n{'network':<28}" + "".join(f"{'test ' + str(s) + 'px':>10}" for s in SLACKS) + f"{'train 0px':>11}"
          + (f"{'held-out 0px':>14}{'chosen step':>13}" if chosen else ""))
    rows = sorted(results, key=lambda r: -r["test"]["0"])
    for r in rows:
        name = f"{r['kind']}/{r['input_type']}/{r['fusion']}"
        sel = ""
        if "selected_step" in r:
            at = next(c for c in r["checkpoints"] if c["step"] == r["selected_step"])
            sel = f"{100 * at['select_auc']:>13.1f}%{r['selected_step']:>13}"
        print(f"{name:<28}" + "".join(f"{100 * r['test'][str(s)]:>9.1f}%" for s in SLACKS)
              + f"{100 * r['train']['0']:>10.1f}%" + sel)
    print(f"{'baseline (flow, §4.5.3)':<28}" + "".join(f"{100 * base['test'][str(s)]:>9.1f}%" for s in SLACKS)
          + f"{100 * base['train']['0']:>10.1f}%")


def _plot(out: Path, results: list[dict], base: dict, data: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..perception import baseline_scores
    from ..perception.data import load_split
    clips = load_split(data, "test")
    y = np.concatenate([c.masks for c in clips])
    best = {}
    for r in results:
        if r["kind"] not in best or r["test"]["0"] > best[r["kind"]]["test"]["0"]:
            best[r["kind"]] = r
    fig, axes = plt.subplots(1, len(best) + 1, figsize=(4 * (len(best) + 1), 3.6), squeeze=False)
    from ..perception import load_model
    from ..perception.train import detect, encode_clips
    shown = []
    for ax, r in zip(axes[0], best.values()):
        net, _ = load_model(out / "models" / f"{r['kind']}-{r['input_type']}-{r['fusion']}.pt")
        probs = [detect(net, x) for x in encode_clips(clips, r["input_type"])]
        shown.append((r, probs))
        _pr_axes(ax, np.concatenate(probs), y, f"{r['kind']} {r['input_type']} {r['fusion']}")
    _pr_axes(axes[0][-1], np.concatenate([baseline_scores(c.frames) for c in clips]), y, "flow baseline")
    fig.tight_layout()
    fig.savefig(out / "pr_curves.png", dpi=100)
    plt.close(fig)
    # one test frame with the most liquid: image, truth, each best network's probability
    k = int(np.argmax(clips[0].masks.sum(axis=(1, 2))))
    panels = [("test frame", clips[0].frames[k]), ("truth", clips[0].masks[k])]
    panels += [(f"{r['kind']}/{r['input_type']}/{r['fusion']}", probs[0][k]) for r, probs in shown]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.8))
    for ax, (title, img) in zip(axes, panels):
        ax.imshow(img, cmap=None if img.ndim == 3 else "magma", vmin=0, vmax=1)
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "detections.png", dpi=100)
    plt.close(fig)
    _plot_selection(out, results)


def _plot_selection(out: Path, results: list[dict]) -> None:
    """Held-out (calibration) and test AUC over training steps per network, chosen step marked."""
    import matplotlib.pyplot as plt
    runs = [r for r in results if r.get("checkpoints")]
    if not runs:
        return
    cols = min(4, len(runs))
    rows = -(-len(runs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False, sharey=True)
    for ax, r in zip(axes.flat, runs):
        steps = [c["step"] for c in r["checkpoints"]]
        ax.plot(steps, [100 * c["select_auc"] for c in r["checkpoints"]], label="held-out (chooses)")
        if "watch_auc" in r["checkpoints"][0]:
            ax.plot(steps, [100 * c["watch_auc"] for c in r["checkpoints"]], "--", label="test (record only)")
        ax.axvline(r["selected_step"], color="k", lw=0.8)
        ax.set_title(f"{r['kind']} {r['input_type']} {r['fusion']}", fontsize=8)
        ax.set_xlabel("step", fontsize=8)
        ax.grid(alpha=0.3)
    axes.flat[0].set_ylabel("AUC % (0 px)")
    axes.flat[0].legend(fontsize=7)
    for ax in list(axes.flat)[len(runs):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "selection.png", dpi=100)
    plt.close(fig)


def _pr_axes(ax, scores, truth, title: str) -> None:
    from ..perception import pr_auc, pr_curve
    for s in SLACKS:
        p, r, _ = pr_curve(scores, truth, s)
        ax.plot(r, p, label=f"{s} px: AUC {100 * pr_auc(p, r):.1f}%")
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
