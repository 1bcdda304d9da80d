"""The thesis's perception findings checked over several datasets: a table from the results of
``liquidtwin evaluate perception`` run once per dataset seed (their ``perception.json``).

One results file per seed (``--seed S``: the dataset's pours and the networks' training
both change). Per network: the test AUC (0 px slack, unseen containers) on every seed and
their mean. Then each finding of issue 8, counted seed by seed, so an ordering that one
dataset happens to show is told from one that holds:

* temporal integration wins: for every input and fusion trained as FCN, MF-FCN and LSTM-FCN,
  on how many seeds LSTM-FCN > MF-FCN > FCN (and each pair alone);
* the fusion: for every network trained with early and late fusion of one image input and
  flow, on how many seeds early beats late;
* the baseline: each network's test AUC over the optical-flow baseline's on the same pours,
  the smallest ratio over the seeds.

    python bench/perception_seeds.py seed0/perception.json seed1/perception.json seed2/perception.json \
        [--json OUT] [--plot OUT.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

KINDS = ("fcn", "mf_fcn", "lstm_fcn")


def _key(r: dict) -> tuple:
    return r["kind"], r["input_type"], r["fusion"]


def table(docs: list[dict]) -> dict:
    """{network key: [test AUC (0 px) per doc, None where that doc lacks it]} in first-seen order."""
    keys = list(dict.fromkeys(_key(r) for d in docs for r in d["results"]))
    by_doc = [{_key(r): r["test"]["0"] for r in d["results"]} for d in docs]
    return {k: [b.get(k) for b in by_doc] for k in keys}


def temporal(tab: dict, n: int) -> list[dict]:
    """Per (input, fusion) with all three kinds: seeds where LSTM-FCN > MF-FCN > FCN, and per pair."""
    out = []
    for inp, fus in dict.fromkeys((k[1], k[2]) for k in tab):
        rows = [tab.get((kind, inp, fus)) for kind in KINDS]
        if any(r is None for r in rows):
            continue
        seeds = [s for s in range(n) if all(r[s] is not None for r in rows)]
        f, m, lstm = ([r[s] for s in seeds] for r in rows)
        out.append({"input": inp, "fusion": fus, "seeds": len(seeds),
                    "lstm>mf>fcn": sum(a > b > c for a, b, c in zip(lstm, m, f)),
                    "lstm>mf": sum(a > b for a, b in zip(lstm, m)), "mf>fcn": sum(a > b for a, b in zip(m, f)),
                    "lstm>fcn": sum(a > b for a, b in zip(lstm, f)),
                    "means": [float(np.mean(v)) if v else float("nan") for v in (f, m, lstm)]})
    return out


def fusion(tab: dict, n: int) -> list[dict]:
    """Per (kind, input) trained with both fusions: seeds where early fusion beats late."""
    out = []
    for kind, inp in dict.fromkeys((k[0], k[1]) for k in tab):
        early, late = tab.get((kind, inp, "early")), tab.get((kind, inp, "late"))
        if early is None or late is None:
            continue
        seeds = [s for s in range(n) if early[s] is not None and late[s] is not None]
        out.append({"kind": kind, "input": inp, "seeds": len(seeds),
                    "early>late": sum(early[s] > late[s] for s in seeds),
                    "mean_early": float(np.mean([early[s] for s in seeds])) if seeds else float("nan"),
                    "mean_late": float(np.mean([late[s] for s in seeds])) if seeds else float("nan")})
    return out


def baseline_ratios(tab: dict, docs: list[dict]) -> dict:
    """{network key: smallest test AUC / baseline test AUC over the seeds it ran on}."""
    base = [d["baseline"]["test"]["0"] for d in docs]
    return {k: min(v / b for v, b in zip(vals, base) if v is not None) for k, vals in tab.items()}


def plot(tab: dict, seeds: list, base: list, path: Path) -> None:
    """One row per network: its test AUC on every seed (dots, one colour per seed) and their
    mean (bar); the flow baseline of every seed as a dashed line of its colour."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = list(tab)
    fig, ax = plt.subplots(figsize=(7, 0.45 * len(keys) + 1.4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    means = [100 * np.mean([v for v in tab[k] if v is not None]) for k in keys]
    ax.barh(range(len(keys)), means, color="0.85", label="mean")
    for s, seed in enumerate(seeds):
        c = colours[s % len(colours)]
        pts = [(100 * tab[k][s], i) for i, k in enumerate(keys) if tab[k][s] is not None]
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], color=c, zorder=3, label=f"seed {seed}")
        ax.axvline(100 * base[s], color=c, ls="--", lw=1)
    ax.set_yticks(range(len(keys)), ["/".join(k) for k in keys])
    ax.invert_yaxis()
    ax.set_xlabel("test AUC %, 0 px slack, unseen containers (dashed: flow baseline)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", type=Path, nargs="+", help="perception.json, one per dataset seed")
    p.add_argument("--json", type=Path, default=None, help="also write the tables here")
    p.add_argument("--plot", type=Path, default=None, help="also draw every network's AUC per seed (PNG)")
    args = p.parse_args(argv)
    docs = [json.loads(f.read_text()) for f in args.results]
    if len(docs) < 2:
        raise SystemExit("give the results of at least two seeds: one dataset cannot tell an ordering from chance")
    seeds = [d.get("seed") for d in docs]
    tab = table(docs)
    n = len(docs)
    ratios = baseline_ratios(tab, docs)
    base = " / ".join(f"{100 * d['baseline']['test']['0']:.1f}" for d in docs)
    print(f"test AUC % (0 px, unseen containers) on seeds {seeds}; flow baseline {base}")
    print(f"{'network':<26}" + "".join(f"{'s' + str(s):>8}" for s in seeds) + f"{'mean':>8}{'min ×base':>11}")
    for k, vals in tab.items():
        got = [v for v in vals if v is not None]
        cells = "".join(f"{'–' if v is None else format(100 * v, '.1f'):>8}" for v in vals)
        print(f"{'/'.join(k):<26}{cells}{100 * np.mean(got):>8.1f}{ratios[k]:>11.1f}")
    temp, fus = temporal(tab, n), fusion(tab, n)
    if temp:
        print("\ntemporal integration (seeds where it holds / seeds): LSTM-FCN > MF-FCN > FCN, and by pair")
        for t in temp:
            f, m, lstm = (100 * x for x in t["means"])
            print(f"  {t['input']}/{t['fusion']}: {t['lstm>mf>fcn']}/{t['seeds']}; LSTM > MF {t['lstm>mf']}, "
                  f"MF > FCN {t['mf>fcn']}, LSTM > FCN {t['lstm>fcn']}; means {f:.1f} / {m:.1f} / {lstm:.1f}")
    if fus:
        print("\nfusion (seeds where early beats late / seeds)")
        for t in fus:
            print(f"  {t['kind']}/{t['input']}: {t['early>late']}/{t['seeds']}; "
                  f"means early {100 * t['mean_early']:.1f}, late {100 * t['mean_late']:.1f}")
    if args.plot:
        plot(tab, seeds, [d["baseline"]["test"]["0"] for d in docs], args.plot)
    if args.json:
        args.json.write_text(json.dumps({"seeds": seeds, "files": [str(f) for f in args.results],
                                         "baseline": [d["baseline"]["test"]["0"] for d in docs],
                                         "test_auc": {"/".join(k): v for k, v in tab.items()},
                                         "min_baseline_ratio": {"/".join(k): v for k, v in ratios.items()},
                                         "temporal": temp, "fusion": fus}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
