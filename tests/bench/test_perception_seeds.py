"""bench/perception_seeds.py: the findings counted seed by seed, on hand-made results of
`evaluate perception` whose orderings are known."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.perception_seeds import baseline_ratios, best_input, fusion, merge_by_seed, table, temporal  # noqa: E402


def _doc(seed, aucs, base=0.05):
    """aucs: {(kind, fusion): test AUC} of grey + flow networks."""
    return {"seed": seed, "baseline": {"test": {"0": base}},
            "results": [{"kind": k, "input_type": "grey_flow", "fusion": f, "test": {"0": v}}
                        for (k, f), v in aucs.items()]}


# seed 0: LSTM > MF > FCN on both fusions, late beats early for every kind;
# seed 1: MF-FCN below FCN on early fusion, early beats late for the FCN only;
# seed 2: lacks the late MF-FCN (a run that trained fewer networks).
DOCS = [
    _doc(0, {("fcn", "early"): 0.10, ("fcn", "late"): 0.20, ("mf_fcn", "early"): 0.15, ("mf_fcn", "late"): 0.25,
             ("lstm_fcn", "early"): 0.30, ("lstm_fcn", "late"): 0.40}),
    _doc(1, {("fcn", "early"): 0.20, ("fcn", "late"): 0.10, ("mf_fcn", "early"): 0.12, ("mf_fcn", "late"): 0.30,
             ("lstm_fcn", "early"): 0.25, ("lstm_fcn", "late"): 0.35}, base=0.04),
    _doc(2, {("fcn", "early"): 0.10, ("fcn", "late"): 0.20, ("mf_fcn", "early"): 0.15,
             ("lstm_fcn", "early"): 0.30, ("lstm_fcn", "late"): 0.40}),
]


def test_orderings_are_counted_per_seed():
    tab = table(DOCS)
    assert tab[("mf_fcn", "grey_flow", "late")] == [0.25, 0.30, None]
    temp = {t["fusion"]: t for t in temporal(tab, 3)}
    assert (temp["early"]["seeds"], temp["early"]["lstm>mf>fcn"], temp["early"]["mf>fcn"]) == (3, 2, 2)
    assert (temp["early"]["lstm>mf"], temp["early"]["lstm>fcn"]) == (3, 3)
    assert (temp["late"]["seeds"], temp["late"]["lstm>mf>fcn"]) == (2, 2)        # seed 2 has no late MF-FCN
    assert temp["early"]["means"] == pytest.approx([0.4 / 3, 0.42 / 3, 0.85 / 3])
    fus = {t["kind"]: t for t in fusion(tab, 3)}
    assert (fus["fcn"]["early>late"], fus["fcn"]["seeds"]) == (1, 3)
    assert (fus["mf_fcn"]["early>late"], fus["mf_fcn"]["seeds"]) == (0, 2)
    assert fus["lstm_fcn"]["early>late"] == 0
    ratios = baseline_ratios(tab, DOCS)
    assert ratios[("fcn", "grey_flow", "early")] == pytest.approx(2.0)            # 0.10 / 0.05 on seeds 0 and 2
    assert ratios[("mf_fcn", "grey_flow", "early")] == pytest.approx(3.0)         # 0.12 / 0.04 on seed 1


def test_inputs_without_an_mf_fcn_compare_lstm_with_fcn_and_the_best_input_is_counted():
    docs = [{"seed": s, "baseline": {"test": {"0": 0.05}},
             "results": [{"kind": k, "input_type": i, "fusion": "early", "test": {"0": v}} for k, i, v in rows]}
            for s, rows in enumerate([
                [("fcn", "flow", 0.10), ("lstm_fcn", "flow", 0.20), ("lstm_fcn", "grey_flow", 0.15)],
                [("fcn", "flow", 0.10), ("lstm_fcn", "flow", 0.05), ("lstm_fcn", "grey_flow", 0.25)],
                [("fcn", "flow", 0.10), ("lstm_fcn", "flow", 0.30)]])]
    tab = table(docs)
    (flow,) = [t for t in temporal(tab, 3) if t["input"] == "flow"]
    assert (flow["lstm>fcn"], flow["seeds"], flow["lstm>mf>fcn"], flow["means"][1]) == (2, 3, None, None)
    best = best_input(tab, 3)
    assert best["seeds"] == 2 and best["wins"] == {"flow": 1, "grey_flow": 1}   # seed 2 lacks grey_flow


def test_runs_of_one_seed_are_merged_and_clashes_refused():
    first = _doc(0, {("fcn", "early"): 0.10, ("lstm_fcn", "early"): 0.30})
    second = _doc(0, {("mf_fcn", "early"): 0.15})
    (merged,) = merge_by_seed([first, second])
    assert sorted(r["kind"] for r in merged["results"]) == ["fcn", "lstm_fcn", "mf_fcn"]
    with pytest.raises(SystemExit, match="two of the given runs"):
        merge_by_seed([first, first])
    with pytest.raises(SystemExit, match="different baselines"):
        merge_by_seed([first, _doc(0, {("mf_fcn", "early"): 0.15}, base=0.07)])
    longer = dict(_doc(1, {("fcn", "early"): 0.2}), iterations={"crop": 2400, "full": 1200})
    with pytest.raises(SystemExit, match="trained differently"):
        merge_by_seed([first, longer])
    assert len(merge_by_seed([dict(longer, seed=2), longer])) == 2       # one recipe throughout: merged


def test_script_prints_the_counts_and_refuses_one_seed(tmp_path):
    files = []
    for d in DOCS:
        f = tmp_path / f"seed{d['seed']}.json"
        f.write_text(json.dumps(d))
        files.append(str(f))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_seeds.py"), *files,
                          "--json", str(tmp_path / "t.json"),
                          "--plot", str(tmp_path / "t.png")], capture_output=True, text=True, check=True).stdout
    assert "grey_flow/early: 2/3" in out and "fcn/grey_flow: 1/3" in out
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"
    assert json.loads((tmp_path / "t.json").read_text())["test_auc"]["mf_fcn/grey_flow/late"] == [0.25, 0.30, None]
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_seeds.py"), files[0]],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "at least two seeds" in bad.stderr


def test_common_test_rescoring_matches_perception_score(tmp_path):
    """bench/perception_common_test.py gives a model the AUC and baseline that `liquidtwin
    perception score` (another code path) gives it on the same pour, and keeps the run's own."""
    import torch

    from liquidtwin.cli import main as cli
    from liquidtwin.perception import build_model, save_model
    from liquidtwin.perception.data import make_dataset
    data, run = tmp_path / "data", tmp_path / "run"
    make_dataset(data, train=0, test=1, seed=3, progress=False)
    torch.manual_seed(0)
    model = save_model(run / "models" / "fcn-grey_flow-early.pt", build_model("fcn", "grey_flow", "early"))
    own = {"0": 0.5, "1": 0.6, "2": 0.7, "4": 0.8}
    recipe = {"iterations": {"crop": 600, "full": 300}, "augment": "flip,colour", "select_every": 0}
    (run / "perception.json").write_text(json.dumps({"seed": 7, **recipe, "baseline": {"test": own}, "results": [
        {"kind": "fcn", "input_type": "grey_flow", "fusion": "early", "test": own}]}))
    out = tmp_path / "common"
    subprocess.run([sys.executable, str(ROOT / "bench" / "perception_common_test.py"), str(run), "--data", str(data),
                    "--out", str(out)], capture_output=True, text=True, check=True)
    assert cli(["perception", "score", str(model), "--data", str(data), "--json", str(tmp_path / "s.json")]) == 0
    ref = json.loads((tmp_path / "s.json").read_text())["splits"]["test"]
    (f,) = out.glob("perception_*.json")
    doc = json.loads(f.read_text())
    assert doc["seed"] == 7 and doc["test_pours"] == 1 and doc["baseline"]["own_test"] == own
    assert {k: doc[k] for k in recipe} == recipe       # the training recipe travels: runs stay told apart
    assert doc["results"][0]["test"] == pytest.approx(ref["auc"], abs=1e-12)
    assert doc["baseline"]["test"] == pytest.approx(ref["baseline"], abs=1e-12)
    assert doc["results"][0]["own_test"] == own
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_common_test.py"), str(tmp_path),
                          "--data", str(data), "--out", str(out)], capture_output=True, text=True)
    assert bad.returncode != 0 and "no perception.json" in bad.stderr
