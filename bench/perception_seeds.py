"""The thesis's perception findings checked over several datasets: a table from the results of
``liquidtwin evaluate perception`` run once per dataset seed (their ``perception.json``).

Results files of one seed (``--seed S``: the dataset's pours and the networks' training
both change) are merged: several runs may each have trained some of its networks. Per network: the test AUC (0 px slack, unseen containers) on every seed and
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


def _mean(values: list) -> float:
    return float(np.mean(values)) if values else float("nan")


#: What makes runs one grid: networks trained for other step counts, augmentations or
#: selection rules are not compared with each other in one table.
RECIPE = ("iterations", "augment", "select_every")


def _recipe(d: dict) -> dict:
    return {k: d.get(k) for k in RECIPE}


def merge_by_seed(docs: list[dict]) -> list[dict]:
    """One doc per seed (first-seen order): the results of every run of that seed together.
    Runs of one seed must agree on the baseline (the same dataset) and not train a network twice;
    every run must share one training recipe (:data:`RECIPE`)."""
    out: dict = {}
    for d in docs:
        if _recipe(d) != _recipe(docs[0]):
            raise SystemExit(f"runs trained differently cannot share a table: seed {d.get('seed')} has "
                             f"{_recipe(d)}, seed {docs[0].get('seed')} {_recipe(docs[0])}")
        seed = d.get("seed")
        if seed not in out:
            out[seed] = {"seed": seed, "baseline": d["baseline"], "results": []}
        m = out[seed]
        if abs(m["baseline"]["test"]["0"] - d["baseline"]["test"]["0"]) > 1e-12:
            raise SystemExit(f"two runs of seed {seed} have different baselines: not the same dataset")
        have = {_key(r) for r in m["results"]}
        twice = [r for r in d["results"] if _key(r) in have]
        if twice:
            raise SystemExit(f"seed {seed}: {'/'.join(_key(twice[0]))} is in two of the given runs")
        m["results"] += d["results"]
    return list(out.values())


def table(docs: list[dict]) -> dict:
    """{network key: [test AUC (0 px) per doc, None where that doc lacks it]} in first-seen order."""
    keys = list(dict.fromkeys(_key(r) for d in docs for r in d["results"]))
    by_doc = [{_key(r): r["test"]["0"] for r in d["results"]} for d in docs]
    return {k: [b.get(k) for b in by_doc] for k in keys}


def temporal(tab: dict, n: int) -> list[dict]:
    """Per (input, fusion) trained as FCN and LSTM-FCN: seeds where LSTM-FCN > FCN; with the
    MF-FCN too, seeds where LSTM-FCN > MF-FCN > FCN and each of its pairs (None without it)."""
    out = []
    for inp, fus in dict.fromkeys((k[1], k[2]) for k in tab):
        f, m, lstm = (tab.get((kind, inp, fus)) for kind in KINDS)
        if f is None or lstm is None:
            continue
        rows = [f, lstm] if m is None else [f, m, lstm]
        seeds = [s for s in range(n) if all(r[s] is not None for r in rows)]
        fv, lv = [f[s] for s in seeds], [lstm[s] for s in seeds]
        mv = None if m is None else [m[s] for s in seeds]
        out.append({"input": inp, "fusion": fus, "seeds": len(seeds),
                    "lstm>mf>fcn": None if mv is None else sum(a > b > c for a, b, c in zip(lv, mv, fv)),
                    "lstm>mf": None if mv is None else sum(a > b for a, b in zip(lv, mv)),
                    "mf>fcn": None if mv is None else sum(a > b for a, b in zip(mv, fv)),
                    "lstm>fcn": sum(a > b for a, b in zip(lv, fv)),
                    "means": [_mean(fv), None if mv is None else _mean(mv), _mean(lv)]})
    return out


def best_input(tab: dict, n: int, kind: str = "lstm_fcn", fusion: str = "early") -> dict:
    """Among ``kind``'s networks with ``fusion`` (single inputs are trained as "early"), on how
    many seeds each input scores highest, over the seeds where all of them ran:
    {"seeds": k, "inputs": [...], "wins": {input: count}}."""
    keys = [k for k in tab if k[0] == kind and k[2] == fusion]
    seeds = [s for s in range(n) if all(tab[k][s] is not None for k in keys)]
    wins = {k[1]: 0 for k in keys}
    for s in seeds:
        wins[max(keys, key=lambda k: tab[k][s])[1]] += 1
    return {"kind": kind, "fusion": fusion, "seeds": len(seeds), "inputs": [k[1] for k in keys], "wins": wins}


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
                    "mean_early": _mean([early[s] for s in seeds]), "mean_late": _mean([late[s] for s in seeds])})
    return out


def baselines(docs: list[dict]) -> list:
    """Every seed's flow-baseline test AUC (0 px)."""
    return [d["baseline"]["test"]["0"] for d in docs]


def baseline_ratios(tab: dict, docs: list[dict]) -> dict:
    """{network key: smallest test AUC / baseline test AUC over the seeds it ran on}."""
    base = baselines(docs)
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
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)      # beside the axes: never over a dot
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", type=Path, nargs="+", help="perception.json of each run (runs of one seed are merged)")
    p.add_argument("--json", type=Path, default=None, help="also write the tables here")
    p.add_argument("--plot", type=Path, default=None, help="also draw every network's AUC per seed (PNG)")
    args = p.parse_args(argv)
    docs = merge_by_seed([json.loads(f.read_text()) for f in args.results])
    if len(docs) < 2:
        raise SystemExit("give the results of at least two seeds: one dataset cannot tell an ordering from chance")
    seeds = [d.get("seed") for d in docs]
    tab = table(docs)
    n = len(docs)
    ratios, base = baseline_ratios(tab, docs), baselines(docs)
    print(f"test AUC % (0 px, unseen containers) on seeds {seeds}; flow baseline "
          + " / ".join(f"{100 * b:.1f}" for b in base))
    print(f"{'network':<26}" + "".join(f"{'s' + str(s):>8}" for s in seeds) + f"{'mean':>8}{'min ×base':>11}")
    for k, vals in tab.items():
        got = [v for v in vals if v is not None]
        cells = "".join(f"{'–' if v is None else format(100 * v, '.1f'):>8}" for v in vals)
        print(f"{'/'.join(k):<26}{cells}{100 * np.mean(got):>8.1f}{ratios[k]:>11.1f}")
    temp, fus, best = temporal(tab, n), fusion(tab, n), best_input(tab, n)
    if temp:
        print("\ntemporal integration (seeds where it holds / seeds): LSTM-FCN > MF-FCN > FCN, and by pair")
        for t in temp:
            f, m, lstm = t["means"]
            if t["lstm>mf>fcn"] is None:
                print(f"  {t['input']}/{t['fusion']}: LSTM > FCN {t['lstm>fcn']}/{t['seeds']} (no MF-FCN); "
                      f"means {100 * f:.1f} / {100 * lstm:.1f}")
                continue
            print(f"  {t['input']}/{t['fusion']}: {t['lstm>mf>fcn']}/{t['seeds']}; LSTM > MF {t['lstm>mf']}, "
                  f"MF > FCN {t['mf>fcn']}, LSTM > FCN {t['lstm>fcn']}; means {100 * f:.1f} / {100 * m:.1f} / {100 * lstm:.1f}")
    if fus:
        print("\nfusion (seeds where early beats late / seeds)")
        for t in fus:
            print(f"  {t['kind']}/{t['input']}: {t['early>late']}/{t['seeds']}; "
                  f"means early {100 * t['mean_early']:.1f}, late {100 * t['mean_late']:.1f}")
    if len(best["inputs"]) > 1:
        print(f"\nbest input of the {best['kind']} networks with {best['fusion']} fusion (seeds it scores highest, "
              f"of {best['seeds']}): " + ", ".join(f"{k} {v}" for k, v in best["wins"].items()))
    if args.plot:
        plot(tab, seeds, base, args.plot)
    if args.json:
        args.json.write_text(json.dumps({"seeds": seeds, "files": [str(f) for f in args.results],
                                         "baseline": base,
                                         "test_auc": {"/".join(k): v for k, v in tab.items()},
                                         "min_baseline_ratio": {"/".join(k): v for k, v in ratios.items()},
                                         "temporal": temp, "fusion": fus, "best_input": best}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
