"""Score the networks of several `evaluate perception` runs on one common set of test pours.

Each run's own test split is 4 pours of its dataset seed, so two seeds' test AUCs differ by
their pours as much as by their networks. This loads a dataset's test split once (e.g. 12
fresh mug → pan pours: ``liquidtwin perception data --out DIR --train 0 --test 12 --calib 0
--seed 100``), its flow baseline once, and scores every model of every given run on it
(``models/KIND-INPUT-FUSION.pt``, the networks its ``perception.json`` lists). Writes, per
run, a ``perception.json``-shaped file (same seed and networks; ``test`` and the baseline's
``test`` are now the common pours') that ``bench/perception_seeds.py`` reads.

    OMP_NUM_THREADS=1 python bench/perception_common_test.py --data DIR RUN_DIR [RUN_DIR …] --out OUT_DIR
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from perception_seeds import RECIPE


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", type=Path, nargs="+", help="output folders of `liquidtwin evaluate perception`")
    p.add_argument("--data", type=Path, required=True, help="dataset whose test split every model is scored on")
    p.add_argument("--out", type=Path, required=True, help="where the rescored perception.json files go")
    args = p.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    from tqdm.auto import tqdm

    from liquidtwin.evaluate.perception import clips_baseline_auc, scores_auc
    from liquidtwin.perception import load_model
    from liquidtwin.perception.data import load_split
    from liquidtwin.perception.train import detect, encode_clips
    if not (args.data / "dataset.json").is_file():
        raise SystemExit(f"{args.data} is not a perception dataset (no dataset.json)")
    clips = load_split(args.data, "test")
    if not clips:
        raise SystemExit(f"{args.data} has no test pours")
    docs = []
    for run in args.runs:
        f = run / "perception.json"
        if not f.is_file():
            raise SystemExit(f"{run} has no perception.json: not an `evaluate perception` output")
        docs.append((run, json.loads(f.read_text())))
    base = clips_baseline_auc(clips)
    args.out.mkdir(parents=True, exist_ok=True)
    encoded: dict = {}
    total = sum(len(d["results"]) for _, d in docs)
    bar = tqdm(total=total, desc="models", unit="net")
    for i, (run, doc) in enumerate(docs):
        results = []
        for r in doc["results"]:
            path = run / "models" / f"{r['kind']}-{r['input_type']}-{r['fusion']}.pt"
            net, meta = load_model(path)
            if meta["input_type"] not in encoded:
                encoded[meta["input_type"]] = encode_clips(clips, meta["input_type"])
            t = time.perf_counter()
            auc = scores_auc([detect(net, x) for x in encoded[meta["input_type"]]], clips)
            results.append({**{k: r[k] for k in ("kind", "input_type", "fusion")}, "test": auc,
                            "own_test": r["test"], "score_s": round(time.perf_counter() - t, 1)})
            bar.update()
        out = {"kind": "perception", "seed": doc.get("seed"), "data": str(args.data), "run": str(run),
               "test_pours": len(clips), **{k: doc.get(k) for k in RECIPE},
               "baseline": {"test": base, "own_test": doc["baseline"]["test"]}, "results": results}
        (args.out / f"perception_{i}_seed{doc.get('seed')}.json").write_text(json.dumps(out, indent=1) + "\n")
    bar.close()
    print(f"{total} networks on {len(clips)} test pours of {args.data}; flow baseline {100 * base['0']:.1f} % (0 px). "
          f"Files in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
