"""Which comparison of masks lets the fill bank rank the true fill first? A sweep of the
δ-likelihood's slack and blur (``liquidtwin.inference.likelihood``) over quick pours with
perfect sensors, scored blind by ``infer_fill``.

    OMP_NUM_THREADS=1 .venv/bin/python bench/fill_likelihood.py --seeds 1 2 3 \
        --settings slack:16 blur:8 blur:16 blur:32 --data /tmp/fill-dev [--json out.json]

Each (scene, seed, fill) pour is generated once into ``--data`` (``generate``: cup into a
bowl, quick, no sensor noise; the truth is the fill it was asked for) and analysed once per
setting with the hypotheses ``--hypotheses`` (fractions × ``QUICK_FILL``). Prints which
hypothesis won and p(truth) per pour and setting, then per setting how often the truth was
ranked first. This is the development set the fill bank's default blur was chosen on; the
report is ``liquidtwin evaluate fill --quick`` (other seeds, sensor noise, hidden effects).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tqdm import tqdm

from liquidtwin.generate import generate
from liquidtwin.generate.catalog import QUICK_FILL
from liquidtwin.inference import fill_name, infer_fill
from liquidtwin.recordings import read_recording


def setting(text: str) -> tuple[str, float]:
    """``slack:PX`` / ``blur:PX`` / ``exact`` → (kind, px)."""
    if text == "exact":
        return "exact", 0.0
    kind, _, px = text.partition(":")
    if kind not in ("slack", "blur") or not px:
        raise argparse.ArgumentTypeError(f"a setting is slack:PX, blur:PX or exact, got {text!r}")
    try:
        value = float(px)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: PX must be a number") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: PX must be >= 0")
    return kind, value


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="generator seeds (default: 1 2 3)")
    p.add_argument("--scenes", nargs="+", default=["pour_partial", "pour_hold", "pour_dump"],
                   help="pour scenes (default: pour_partial pour_hold pour_dump)")
    p.add_argument("--fills", type=float, nargs="+", default=[0.3, 0.9], help="true fills (default: 0.3 0.9)")
    p.add_argument("--hypotheses", type=float, nargs="+", default=[0.0, 0.3, 0.9],
                   help="fill hypotheses, fractions of capacity (default: 0 0.3 0.9)")
    p.add_argument("--settings", type=setting, nargs="+", default=[("slack", 16.0), ("blur", 32.0)],
                   help="likelihood comparisons: slack:PX, blur:PX (px at 640x480) or exact "
                        "(default: slack:16 blur:32)")
    p.add_argument("--tracking", default="open_loop", help="tracker of each hypothesis (default: open_loop)")
    p.add_argument("--data", type=Path, required=True, help="where the pours are cached")
    p.add_argument("--json", type=Path, default=None, help="write every posterior here")
    a = p.parse_args(argv)
    bad = [f for f in a.fills if f not in a.hypotheses]
    if bad:
        p.error(f"true fills {bad} are not among the hypotheses {a.hypotheses}")
    a.data.mkdir(parents=True, exist_ok=True)
    rows = []
    pours = [(sc, seed, f) for sc in a.scenes for seed in a.seeds for f in a.fills]
    for scene, seed, fill in tqdm(pours, desc="pours", unit="pour"):
        path = a.data / f"{scene}-s{seed}-f{fill:g}.mcap"
        if not path.exists():
            generate(scene, path, seed=seed, quick=True, noise=False,
                     choices={"source": "cup", "target": "bowl", "fraction": fill})
        rec = read_recording(path, images=False)
        truth = fill_name(fill)
        row = {"scene": scene, "seed": seed, "truth": truth, "settings": {}}
        for kind, px in a.settings:
            post = infer_fill(rec, fractions=a.hypotheses, scale=QUICK_FILL, tracking=a.tracking,
                              slack_px=px if kind == "slack" else 0.0, blur_px=px if kind == "blur" else 0.0)
            row["settings"][f"{kind}:{px:g}"] = {"best": post.best, "names": post.names,
                                                 "probability": post.probability.tolist(),
                                                 "p_truth": float(post.probability[post.names.index(truth)])}
        rows.append(row)
        tqdm.write(f"{scene:<13} seed {seed} {truth:>5}: " + "  ".join(
            f"{k} {v['best']} ({v['p_truth']:.3f})" for k, v in row["settings"].items()))
    summary = {k: sum(r["settings"][k]["best"] == r["truth"] for r in rows) for k in rows[0]["settings"]}
    for k, n in summary.items():
        print(f"{k:<10} truth ranked first {n}/{len(rows)}")
    doc = {"tracking": a.tracking, "hypotheses": a.hypotheses, "rows": rows, "ranked_first": summary,
           "pours": len(rows)}
    if a.json:
        a.json.write_text(json.dumps(doc, indent=1))
    return doc


if __name__ == "__main__":
    main()
