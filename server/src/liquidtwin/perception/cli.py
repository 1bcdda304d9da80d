"""``liquidtwin perception data|train|detect|register``: the detector's dataset, training, a
look at a recording, and the thermal → colour registration.

``data`` generates the RGB pours (perception.data); ``train`` trains one detector on its
training split, picks the F1-best threshold on the calibration split (held-out pours of the
training containers; the training split when the dataset has none), scores train and
unseen-container test AUC and writes a model file; ``calibrate`` re-picks a model's threshold
on a dataset's calibration split (the shipped one is ``server/src/liquidtwin/data/detector.pt``,
re-made by the command in data/README.md); ``detect`` runs a model over a recording's
images and prints AUC against its masks (when it has them).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

HELP = "liquid detection from RGB: make the dataset, train a detector, run one on a recording"


def configure(p: argparse.ArgumentParser) -> None:
    from .inputs import AUGMENT_HELP, FUSIONS, INPUTS
    from .nets import KINDS
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    d = sub.add_parser("data", help="generate the training and unseen-container test pours",
                       description="generate the training and unseen-container test pours (RGB + true masks)")
    d.add_argument("--out", type=Path, required=True, metavar="DIR")
    d.add_argument("--train", type=int, default=12, help="training pours (default: %(default)s)")
    d.add_argument("--test", type=int, default=4, help="test pours (default: %(default)s)")
    d.add_argument("--calib", type=int, default=3,
                   help="calibration pours: training containers, fresh seeds; the threshold is chosen there "
                        "(default: %(default)s)")
    d.add_argument("--seed", type=int, default=0, help="(default: %(default)s)")
    d.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    t = sub.add_parser("train", help="train one detector and write its model file",
                       description="train one detector on DATA's training pours; write a weights_only model file")
    t.add_argument("--data", type=Path, required=True, metavar="DIR", help="a dataset made by `perception data`")
    t.add_argument("--out", type=Path, required=True, metavar="MODEL.pt")
    t.add_argument("--kind", choices=KINDS, default="lstm_fcn", help="(default: %(default)s)")
    t.add_argument("--input", choices=sorted(INPUTS), default="grey_flow", help="(default: %(default)s)")
    t.add_argument("--fusion", choices=FUSIONS, default="early", help="(default: %(default)s)")
    t.add_argument("--crop-iterations", type=int, default=600, help="pre-training steps on crops (default: %(default)s)")
    t.add_argument("--full-iterations", type=int, default=300, help="steps on full frames (default: %(default)s)")
    t.add_argument("--select-every", type=int, default=0, metavar="N",
                   help="score on the calibration pours every N steps and keep the best weights "
                        "(0: keep the last; default: %(default)s)")
    t.add_argument("--augment", default="", metavar="flip,colour",
                   help=AUGMENT_HELP)
    t.add_argument("--init", type=Path, default=None, metavar="FCN.pt",
                   help="start the input block from this trained detector (same input and fusion)")
    t.add_argument("--seed", type=int, default=0, help="(default: %(default)s)")
    t.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    t.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    c = sub.add_parser("calibrate", help="choose a detector's mask threshold on a dataset's calibration pours",
                       description="set MODEL's mask threshold to the F1-best (0 px) on DATA's calibration split "
                                   "(pours of the training containers the detector was not trained on); "
                                   "weights unchanged")
    c.add_argument("model", type=Path, metavar="MODEL.pt")
    c.add_argument("--data", type=Path, required=True, metavar="DIR", help="a dataset with a calib split")
    c.add_argument("--out", type=Path, default=None, metavar="MODEL.pt", help="write here (default: over MODEL)")
    sc = sub.add_parser("score", help="a trained detector's AUC on a dataset's splits",
                        description="score MODEL on DATA's pours without training: AUC of the precision-recall "
                                    "curve at 0/1/2/4 px slack per split, beside the optical-flow baseline's "
                                    "(thesis §4.5.3). Use it to check a model on pours it has not seen, e.g. a "
                                    "dataset made with another --seed")
    sc.add_argument("model", type=Path, metavar="MODEL.pt")
    sc.add_argument("--data", type=Path, required=True, metavar="DIR", help="a dataset of `perception data`")
    sc.add_argument("--splits", nargs="+", default=["test"], choices=["train", "test", "calib"],
                    help="which splits (default: test)")
    sc.add_argument("--json", type=Path, default=None, metavar="OUT.json", help="also write the AUCs here")
    g = sub.add_parser("register", help="thermal → colour affine map from heated-chessboard image pairs",
                       description="fit the thermal → colour affine map from one or more heated-chessboard pairs "
                                   "(findChessboardCorners in both, least squares); prints it and the RMS")
    g.add_argument("--thermal", type=Path, nargs="+", required=True, metavar="IMG",
                   help="thermal images of the board (any bit depth OpenCV reads, e.g. 16-bit PNG)")
    g.add_argument("--colour", type=Path, nargs="+", required=True, metavar="IMG", help="colour images, same order")
    g.add_argument("--pattern", default="7x5", metavar="COLSxROWS", help="inner corners (default: %(default)s)")
    g.add_argument("--out", type=Path, default=None, metavar="AFFINE.json", help="write the map here")
    r = sub.add_parser("detect", help="run a detector over a recording's RGB images",
                       description="run a detector over a recording's RGB images; AUC against its masks")
    r.add_argument("recording", type=Path, metavar="REC.mcap")
    r.add_argument("--model", type=Path, default=None, metavar="MODEL.pt", help="default: the shipped model")


def best_threshold(probs, masks) -> float:
    """The threshold with the highest F1 (0 px slack) over the given frames."""
    import numpy as np

    from .metrics import pr_curve
    p, r, thr = pr_curve(np.concatenate(probs), np.concatenate(masks), 0)
    f1 = np.where(p + r > 0, 2 * p * r / np.maximum(p + r, 1e-12), 0.0)
    return float(thr[int(np.argmax(f1))])


def run(args: argparse.Namespace) -> int:
    if args.action == "data":
        from .data import make_dataset
        m = make_dataset(args.out, train=args.train, test=args.test, calib=args.calib, seed=args.seed,
                         progress=not args.no_progress)
        print(f"{len(m['train'])} training + {len(m['test'])} test + {len(m['calib'])} calibration pours "
              f"in {args.out}")
        return 0
    if args.action == "train":
        return _train(args)
    if args.action == "calibrate":
        return _calibrate(args)
    if args.action == "register":
        return _register(args)
    if args.action == "score":
        return _score(args)
    return _detect(args)


def _register(args) -> int:
    import cv2

    from .thermal import CalibrationError, register_thermal
    if len(args.thermal) != len(args.colour):
        raise SystemExit(f"--thermal and --colour need the same number of images ({len(args.thermal)} vs "
                         f"{len(args.colour)})")
    try:
        pattern = tuple(int(v) for v in args.pattern.lower().split("x"))
        assert len(pattern) == 2 and min(pattern) >= 2
    except (ValueError, AssertionError):
        raise SystemExit(f"--pattern takes inner corners as COLSxROWS, e.g. 7x5; got {args.pattern!r}") from None
    thermal, colour = [], []
    for t, c in zip(args.thermal, args.colour):
        ti, ci = cv2.imread(str(t), cv2.IMREAD_UNCHANGED), cv2.imread(str(c), cv2.IMREAD_COLOR)
        if ti is None or ci is None:
            raise SystemExit(f"cannot read {t if ti is None else c} as an image")
        thermal.append(ti if ti.ndim == 2 else cv2.cvtColor(ti, cv2.COLOR_BGR2GRAY))
        colour.append(cv2.cvtColor(ci, cv2.COLOR_BGR2RGB))
    try:
        affine, rms = register_thermal(thermal, colour, pattern)
    except CalibrationError as e:
        raise SystemExit(f"liquidtwin perception register: {e}") from None
    print("thermal → colour affine (colour px = A · [u, v, 1]):")
    for row in affine:
        print("  " + "  ".join(f"{v:12.6f}" for v in row))
    print(f"RMS residual {rms:.3f} colour px over {len(args.thermal)} pair(s)")
    if args.out:
        args.out.write_text(json.dumps({"affine": affine.tolist(), "rms_px": rms, "pattern": list(pattern),
                                        "pairs": [[str(t), str(c)] for t, c in zip(args.thermal, args.colour)]},
                                       indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


def _train(args) -> int:
    import torch

    from ..evaluate.perception import scores_auc
    from .data import SIZE, load_split
    from .nets import parameter_count
    from .inputs import parse_augment
    from .train import TrainConfig, detect, encode_clips, train
    from .weights import save_model
    try:
        augment = parse_augment(args.augment)
    except ValueError as e:
        raise SystemExit(f"--augment: {e}")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    calib = load_split(args.data, "calib")
    if args.select_every < 0 or (args.select_every and not calib):
        raise SystemExit(f"--select-every takes N >= 0 and chooses on the calibration pours; {args.data} has "
                         f"{len(calib)} (add them with `liquidtwin perception data --out {args.data} --calib 3`)")
    train_clips, test_clips = load_split(args.data, "train"), load_split(args.data, "test")
    cfg = TrainConfig(kind=args.kind, input_type=args.input, fusion=args.fusion, crop_iterations=args.crop_iterations,
                      full_iterations=args.full_iterations, seed=args.seed, select_every=args.select_every,
                      augment=augment)
    from .weights import load_model
    init = load_model(args.init)[0] if args.init else None
    net, info = train(train_clips, cfg, progress=not args.no_progress, init=init, select_on=calib or None)
    probs = [detect(net, x) for x in encode_clips(train_clips, cfg.input_type)]
    thr_from = {"split": "calib" if calib else "train", "pours": len(calib or train_clips)}
    thr = (best_threshold([detect(net, x) for x in encode_clips(calib, cfg.input_type)], [c.masks for c in calib])
           if calib else best_threshold(probs, [c.masks for c in train_clips]))
    auc = {"train": scores_auc(probs, train_clips),
           "test": scores_auc([detect(net, x) for x in encode_clips(test_clips, cfg.input_type)], test_clips)}
    manifest = json.loads((args.data / "dataset.json").read_text())
    meta = {"size": list(SIZE), "threshold": thr, "threshold_from": thr_from, "trained": info["config"], "train_wall_s": info["wall_s"],
            "dataset": {"seed": manifest["seed"], "train": len(manifest["train"]), "test": len(manifest["test"])},
            "auc": auc, "parameters": parameter_count(net), "selected_step": info.get("selected_step"),
            "init": None if args.init is None else args.init.name, "made": time.strftime("%Y-%m-%d")}
    save_model(args.out, net, meta)
    size_kb = args.out.stat().st_size / 1024
    print(f"{cfg.kind}/{cfg.input_type}/{cfg.fusion}: {parameter_count(net)} parameters, {size_kb:.0f} KB, "
          f"trained {info['wall_s']:.0f} s; threshold {thr:.2f} (F1-best on {thr_from['pours']} "
          f"{thr_from['split']} pours)")
    if "selected_step" in info:
        print(f"  weights of step {info['selected_step']} of {cfg.crop_iterations + cfg.full_iterations} "
              f"(best 0 px AUC on the {len(calib)} calibration pours)")
    for split in ("train", "test"):
        print(f"  {split:<5} AUC " + "  ".join(f"{k} px {100 * v:.1f}%" for k, v in auc[split].items()))
    print(f"wrote {args.out}")
    return 0


def _calibrate(args) -> int:
    import numpy as np

    from .data import SIZE, load_split
    from .metrics import pr_curve
    from .train import detect, encode_clips
    from .weights import load_model, save_model
    net, meta = load_model(args.model)
    clips = load_split(args.data, "calib")
    if not clips:
        raise SystemExit(f"{args.data} has no calibration pours; add them with "
                         f"`liquidtwin perception data --out {args.data} --calib 3` (same --seed as the dataset)")
    probs = [detect(net, x) for x in encode_clips(clips, meta["input_type"])]
    masks = [c.masks for c in clips]
    thr = best_threshold(probs, masks)
    p, r, t = pr_curve(np.concatenate(probs), np.concatenate(masks), 0)

    def iou(threshold):                 # pooled pixel IOU at a threshold: F1 / (2 − F1)
        k = min(int(np.searchsorted(t, threshold)), len(t) - 1)
        f1 = 2 * p[k] * r[k] / max(p[k] + r[k], 1e-12)
        return f1 / (2 - f1)
    old = float(meta.get("threshold", 0.5))
    # a model file of `evaluate perception` made before it stored the size was trained at SIZE
    meta = {"size": list(SIZE), **meta, "threshold": thr, "threshold_from": {"split": "calib", "pours": len(clips),
                                                         "dataset_seed": json.loads(
                                                             (args.data / "dataset.json").read_text())["seed"]}}
    out = args.out or args.model
    save_model(out, net, meta)
    print(f"threshold {old:.2f} → {thr:.2f} (F1-best on {len(clips)} calibration pours); "
          f"pixel IOU there {iou(old):.3f} → {iou(thr):.3f}")
    print(f"wrote {out}")
    return 0


def _score(args) -> int:
    from ..evaluate.perception import clips_baseline_auc, scores_auc
    from .data import load_split
    from .train import detect, encode_clips
    from .weights import load_model
    if not (args.data / "dataset.json").is_file():
        raise SystemExit(f"{args.data} is not a perception dataset (no dataset.json); make one with "
                         f"`liquidtwin perception data --out {args.data}`")
    net, meta = load_model(args.model)
    doc = {"model": str(args.model), "data": str(args.data), "splits": {}}
    name = f"{meta.get('kind', '?')}/{meta['input_type']}/{meta.get('fusion', '?')}"
    print(f"{name} on {args.data} (AUC, 0 / 1 / 2 / 4 px slack)")
    for split in args.splits:
        clips = load_split(args.data, split)
        if not clips:
            print(f"  {split:<6} no pours")
            continue
        auc = scores_auc([detect(net, x) for x in encode_clips(clips, meta["input_type"])], clips)
        base = clips_baseline_auc(clips)
        doc["splits"][split] = {"pours": len(clips), "auc": auc, "baseline": base}
        fmt = lambda a: " / ".join(f"{100 * a[k]:.1f}" for k in sorted(a, key=int))
        print(f"  {split:<6} {len(clips)} pours: {fmt(auc)} %   (flow baseline {fmt(base)} %)")
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def _detect(args) -> int:
    import numpy as np

    from ..recordings import read_recording
    from .metrics import auc
    from .stream import StreamDetector
    det = StreamDetector.from_file(args.model)
    rec = read_recording(args.recording)
    if not rec.images:
        raise SystemExit(f"{args.recording} has no RGB images")
    for cam, (stamps, images) in sorted(rec.images.items()):
        t0 = time.perf_counter()
        probs = np.stack([det.probability(cam, im) for im in images])
        fps = len(images) / (time.perf_counter() - t0)
        line = f"{cam}: {len(images)} frames at {images[0].shape[1]}×{images[0].shape[0]}, {fps:.1f} fps"
        if cam in rec.masks:
            ts, masks = rec.masks[cam]
            at = {int(t): k for k, t in enumerate(stamps)}
            both = [(at[int(t)], m) for t, m in zip(ts, masks) if int(t) in at]
            if both:
                p = np.stack([probs[k] for k, _ in both])
                y = np.stack([m for _, m in both])
                line += f"; AUC vs recorded masks: {100 * auc(p, y, 0):.1f}% (0 px), {100 * auc(p, y, 2):.1f}% (2 px)"
        print(line)
    return 0
