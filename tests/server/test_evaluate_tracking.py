"""``liquidtwin evaluate tracking`` on one short generated pour: the CLI end to end (table rows,
JSON, PNGs, n/a for a tracker that cannot run), the ceiling above every tracker, and the
table's pooling on a hand-made result list."""

import argparse
import json

import numpy as np
import pytest

from liquidtwin.cli import main as cli_main
from liquidtwin.evaluate import cases, ensure
from liquidtwin.evaluate.tracking import ROWS, format_table, table
from realisations import SKINS, realisation

#: Pose samples replayed (60 Hz): the first case (partial pour from a 30 % cup, 3.5 s) is in
#: view from ~1.3 s. Measured over this many (evaluate tracking --quick, seed 0): open loop
#: 0.14, MAP 0.23, warp 0.21, ceiling 0.82; over 150 samples MAP is still level with open loop.
#: On stop 41's world (generate/world.py) MAP gains +0.017 here (0.162 against 0.144), and
#: with the default neighbour skin of stop 47 (the same physics in another float rounding)
#: −0.004 (0.151 against 0.155): one chaotic pour says nothing about the MAP filter, and over
#: realisations of three pours its gain is not distinguishable from zero either
#: (test_tracking_spnets.py, POUR_MARGIN's comment). Only the ceiling bounds it here.
FRAMES = 210
#: The warp field against open loop on this one pour is not asserted. Over three realisations
#: of the model's chaos (realisations.SKINS) it gained +0.062, +0.106, +0.102 at stop 47; on
#: the pour that stop 48's numerics generate (per-particle collision pieces: the same physics,
#: another pour) −0.003, −0.039, −0.056, and stop 47's code replaying that pour gained +0.008
#: (0.190 against 0.182; uncommitted check): the pour, not the tracker, sets the sign. On single
#: pours the warp field is not always ahead; the benchmark's 18 pours carry that claim
#: (README, issue 5) and test_tracking_spnets.py asserts SPNets+perception's gain over pours.


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """The first quick benchmark case (generated once into a temp dir), evaluated by the CLI
    for every tracker over its first FRAMES pose samples."""
    tmp = tmp_path_factory.mktemp("evaltrack")
    data, out = tmp / "data", tmp / "out"
    ensure(cases(quick=True, trials=1)[:1], data, progress=False)
    rc = cli_main(["evaluate", "tracking", "--quick", "--trials", "1", "--cases", "1", "--frames", str(FRAMES),
                   "--trackers", "open_loop", "map_filter", "warp_field",
                   "--data", str(data), "--out", str(out), "--no-progress"])
    assert rc in (0, None)
    return out, data, json.loads((out / "results.json").read_text())


def _mean(series, min_px=50):
    v = [i for i, n in zip(series["iou"], series["observed_px"]) if n >= min_px]
    assert len(v) >= 5, "too few frames with liquid in view to compare trackers"
    return float(np.mean(v))


def test_cli_writes_the_table_json_and_figures(evaluated, capsys):
    out, _, doc = evaluated
    assert (out / "table.png").stat().st_size > 5000 and (out / "iou_time.png").stat().st_size > 5000
    assert doc["quick"] and doc["frames"] == FRAMES and len(doc["cases"]) == 1
    case = doc["cases"][0]["case"]
    assert case["seed"] == 0 and case["source"] == "cup" and case["name"].endswith("-s0-q")
    assert set(doc["table"]) == set(ROWS)
    assert doc["columns"] == ["open_loop", "map_filter", "warp_field", "ceiling"]
    series = doc["cases"][0]["series"]
    # Rows: a cup case at 30 % fills the cup, 30 % and overall rows; bottle/60/90 have no frames.
    for col in ("open_loop", "map_filter", "warp_field", "ceiling"):
        want = _mean(series[col])
        for row in ("cup", "30 %", "overall"):
            assert doc["table"][row][col] == pytest.approx(want)
        for row in ("bottle", "60 %", "90 %"):
            assert doc["table"][row][col] is None
    ceiling = series["ceiling"]                  # IOU <= smaller mask / larger mask (1 when both empty)
    assert len(ceiling["model_px"]) == len(ceiling["iou"]) and sum(ceiling["model_px"]) > 0
    for i, m, o in zip(ceiling["iou"], ceiling["model_px"], ceiling["observed_px"]):
        assert i <= (min(m, o) / max(m, o) if max(m, o) else 1.0) + 1e-9
    lines = doc["table_text"].splitlines()
    assert [ln.split()[0] for ln in lines[1:7]] == ["cup", "bottle", "30", "60", "90", "overall"]
    assert ">= 50 px" in lines[-1]
    # ARCHITECTURE.md: DIR/NAME.json with the headline figure
    named = json.loads((out / "tracking.json").read_text())
    best = max(("map_filter", "warp_field"), key=lambda c: doc["table"]["overall"][c])
    assert named["headline"] == {"name": f"best closed-loop overall IOU ({best})",
                                 "value": doc["table"]["overall"][best], "unit": "IOU"}


def test_a_tracker_a_session_cannot_run_is_reported_not_available(evaluated, monkeypatch):
    """Generic n/a: any mode whose engine raises EngineError INFEASIBLE gets no series (and an
    n/a cell); other errors are not swallowed."""
    import liquidtwin.evaluate.tracking as T
    from liquidtwin.session.errors import BAD_REQUEST, INFEASIBLE, EngineError
    _, data, doc = evaluated
    real = T.engine_for

    def fake(rec, tracking="open_loop", **kw):
        if tracking == "warp_field":
            raise EngineError(INFEASIBLE, "not in this build")
        return real(rec, tracking, **kw)
    monkeypatch.setattr(T, "engine_for", fake)
    path = doc["cases"][0]["recording"]
    r = T.evaluate_case(path, ("open_loop", "warp_field"), frames=4)
    assert r["series"]["warp_field"] is None and "not in this build" in r["unavailable"]["warp_field"]
    assert len(r["series"]["open_loop"]["iou"]) == len(r["series"]["ceiling"]["iou"]) == 2
    tab = table([{"case": doc["cases"][0]["case"], **r}], ["open_loop", "warp_field"], 0)
    assert tab["overall"]["warp_field"] is None and tab["overall"]["open_loop"] is not None

    def broken(rec, tracking="open_loop", **kw):
        raise EngineError(BAD_REQUEST, "bad spec")
    monkeypatch.setattr(T, "engine_for", broken)
    with pytest.raises(EngineError):
        T.evaluate_case(path, ("open_loop",), frames=4)


def test_every_tracker_stays_below_the_ceiling_in_every_realisation(evaluated):
    """The CLI's run (the default neighbour skin) and two more realisations of the model's
    chaos on the same recording (``realisations.SKINS``): the ceiling above every tracker in
    each. The warp field against open loop is not asserted (the comment below FRAMES)."""
    import liquidtwin.evaluate.tracking as T
    _, _, doc = evaluated
    runs = [doc["cases"][0]]
    for skin in SKINS[1:]:
        with realisation(skin):
            runs.append(T.evaluate_case(doc["cases"][0]["recording"], ("open_loop", "map_filter", "warp_field"),
                                        frames=FRAMES))
    for skin, r in zip(SKINS, runs):
        s = r["series"]
        # Every tracker sees the same mask frames.
        assert s["open_loop"]["t_s"] == s["warp_field"]["t_s"] == s["map_filter"]["t_s"] == s["ceiling"]["t_s"]
        open_loop, warp, map_ = _mean(s["open_loop"]), _mean(s["warp_field"]), _mean(s["map_filter"])
        ceiling = _mean(s["ceiling"])
        print(f"\nskin {skin} h: open loop {open_loop:.3f}, MAP {map_:.3f}, warp {warp:.3f}, ceiling {ceiling:.3f}")
        assert ceiling > max(warp, map_, open_loop), (ceiling, warp, map_, open_loop)


def test_table_pools_frames_per_row_and_marks_missing_columns():
    def res(source, fraction, iou, px):
        return {"case": {"source": source, "fraction": fraction},
                "series": {"a": {"iou": iou, "observed_px": px}, "b": None}}
    results = [res("cup", 0.3, [0.2, 0.4, 0.9], [60, 50, 49]),        # the 49 px frame does not count
               res("bottle", 0.9, [0.6], [500])]
    tab = table(results, ["a", "b"], 50)
    assert tab["cup"]["a"] == pytest.approx(0.3) and tab["30 %"]["a"] == pytest.approx(0.3)
    assert tab["bottle"]["a"] == pytest.approx(0.6) and tab["90 %"]["a"] == pytest.approx(0.6)
    assert tab["overall"]["a"] == pytest.approx(0.4)                     # pooled frames, not case means
    assert tab["60 %"]["a"] is None and all(tab[r]["b"] is None for r in ROWS)
    text = format_table(tab, ["a", "b"], 50, "note")
    assert "n/a" in text and "40.0 %" in text


def test_iterations_option_sets_the_analysing_models_solver(evaluated):
    """``--iterations N`` is a model setting: the engine that replays the recording solves N
    PBF iterations per step (the recording's spec says 4); nonsense is refused."""
    from liquidtwin.evaluate.cli import with_model_options
    from liquidtwin.evaluate.replay import engine_for
    from liquidtwin.recordings import read_recording
    path = evaluated[2]["cases"][0]["recording"]
    assert engine_for(read_recording(path, images=False), "open_loop")._scene.model.iterations == 4
    rec = with_model_options(read_recording(path, images=False), 6)
    assert rec.spec.simulation.iterations == 6
    assert engine_for(rec, "open_loop")._scene.model.iterations == 6
    assert with_model_options(read_recording(path, images=False), None).spec.simulation.iterations == 4
    for bad in (0, -2, 2.5, True):
        with pytest.raises(SystemExit, match="--iterations"):
            with_model_options(rec, bad)


def test_impact_iterations_option_solves_each_recordings_own_fall(evaluated, capsys):
    """``--iterations impact`` gives each recording the count its own scene's longest fall
    needs, read from its spec alone: the generator's rule for the same setup (8 for this cup
    over its bowl), the same liquid (reference_iterations 4), recorded per case."""
    from liquidtwin.evaluate.cli import iterations_arg, with_model_options
    from liquidtwin.generate.catalog import build_setup
    from liquidtwin.generate.world import impact_iterations
    from liquidtwin.recordings import read_recording
    out, data, doc = evaluated
    case = cases(quick=True, trials=1)[0]
    setup = build_setup(case.scene, np.random.default_rng(case.seed), quick=True, source=case.source,
                        fraction=case.fraction)
    rec = with_model_options(read_recording(doc["cases"][0]["recording"], images=False), "impact")
    assert (rec.spec.simulation.iterations, rec.spec.simulation.reference_iterations) == (impact_iterations(setup), 4)
    assert rec.spec.simulation.iterations == 8
    assert doc["cases"][0]["iterations"] == 4                   # the run above: the recording's own count
    for bad in ("0", "many", "2.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            iterations_arg(bad)
    assert iterations_arg("impact") == "impact" and iterations_arg("6") == 6
    rc = cli_main(["evaluate", "tracking", "--quick", "--trials", "1", "--cases", "1", "--frames", "20",
                   "--trackers", "open_loop", "--iterations", "impact", "--data", str(data),
                   "--out", str(out / "impact"), "--no-progress"])
    assert rc in (0, None)
    run = json.loads((out / "impact" / "results.json").read_text())
    assert run["iterations"] == "impact" and run["cases"][0]["iterations"] == 8
    assert "model solver iterations impact (8 a recording)" in capsys.readouterr().out


def test_model_options_cap_the_moves_and_cut_the_wall_pairs(evaluated, capsys):
    """``--max-correction S``: the replaying engine's model moves a particle at most S rest
    spacings per solver iteration; ``--cut-wall-pairs``: it drops neighbour pairs across walls
    (each alone; without them SPNets as published). Recorded in results.json and named in the
    table's note; nonsense is refused."""
    from liquidtwin.evaluate.cli import max_correction_arg, with_model_options
    from liquidtwin.evaluate.replay import engine_for
    from liquidtwin.recordings import read_recording
    out, data, doc = evaluated

    def model(**kw):
        return engine_for(with_model_options(read_recording(doc["cases"][0]["recording"], images=False), None, **kw),
                          "open_loop")._scene.model
    plain, capped, cut = model(), model(max_correction=0.5), model(cut_wall_pairs=True)
    assert plain.max_correction is None and plain.wall_pairs
    assert capped.max_correction == pytest.approx(0.5 * capped.spacing) and capped.wall_pairs
    assert cut.max_correction is None and not cut.wall_pairs
    assert capped.iterations == cut.iterations == plain.iterations
    assert doc["max_correction"] is None and doc["cut_wall_pairs"] is False
    rc = cli_main(["evaluate", "tracking", "--quick", "--trials", "1", "--cases", "1", "--frames", "20",
                   "--trackers", "open_loop", "--max-correction", "0.5", "--cut-wall-pairs", "--data", str(data),
                   "--out", str(out / "cap"), "--no-progress"])
    assert rc in (0, None)
    run = json.loads((out / "cap" / "results.json").read_text())
    assert run["max_correction"] == 0.5 and run["cut_wall_pairs"] is True
    assert "model moves capped at 0.5 spacings, model pairs cut at walls" in capsys.readouterr().out
    for bad in ("0", "-1", "nan", "inf", "half"):
        with pytest.raises(argparse.ArgumentTypeError):
            max_correction_arg(bad)
    for bad in (0.0, -0.5, float("nan"), True):
        with pytest.raises(SystemExit, match="--max-correction"):
            model(max_correction=bad)


def test_cases_option_picks_a_range_that_keeps_each_case_and_its_seed():
    # --cases A:B runs a later part of the benchmark with the very cases (and so the cached
    # recordings) of a full run; N is the first N; nonsense is refused by the parser.
    import argparse

    from liquidtwin.evaluate.cli import case_range, selected_cases
    full = cases(quick=True, trials=1)
    args = argparse.Namespace(quick=True, trials=1, seed=0, cases=case_range("9:18"), frames=None)
    assert [c.name for c in selected_cases(args)] == [c.name for c in full[9:18]]
    assert all(c.source == "bottle" for c in full[9:18]) and all(c.source == "cup" for c in full[:9])
    args.cases = case_range("2")
    assert [c.seed for c in selected_cases(args)] == [full[0].seed, full[1].seed]
    for bad in ("0", "5:5", "-1:3", "x", "3:"):
        with pytest.raises(argparse.ArgumentTypeError):
            case_range(bad)
    args.cases = case_range("40:50")
    with pytest.raises(SystemExit, match="18 cases"):
        selected_cases(args)


def test_scoring_against_reference_masks_reproduces_the_engines_iou(evaluated):
    """``replay(reference=…)`` scores the model (read back from the correction's overlay)
    against other masks; given the very masks the tracker corrects with, it must reproduce the
    engine's own IOU frame by frame."""
    from liquidtwin.evaluate.replay import engine_for, replay
    from liquidtwin.recordings import read_recording
    rec = read_recording(evaluated[2]["cases"][0]["recording"], images=False)
    cam = next(iter(rec.masks))
    own = replay(rec, engine_for(rec, "warp_field"), frames=FRAMES)
    ref = replay(rec, engine_for(rec, "warp_field"), frames=FRAMES, reference=rec.masks[cam][1])
    assert sum(n >= 50 for n in own.observed_px) >= 5
    assert ref.observed_px == own.observed_px
    assert ref.iou == pytest.approx(own.iou, abs=1e-12)
    with pytest.raises(ValueError, match="reference masks"):
        replay(rec, engine_for(rec, "open_loop"), frames=4, reference=rec.masks[cam][1][:3])


def test_detected_masks_feed_the_tracker_and_are_scored_against_the_recorded_ones(tmp_path, capsys):
    """``--masks recorded detected``: RGB benchmark recordings (other names), a ``/detected``
    column for the closed-loop tracker only, scored on the same frames against the same
    recorded masks as the recorded-mask column but from other corrections; the detector's own
    agreement with the recorded masks is reported; a broken model file is refused up front."""
    data, out = tmp_path / "data", tmp_path / "out"
    args = ["evaluate", "tracking", "--quick", "--trials", "1", "--cases", "1", "--frames", str(FRAMES),
            "--trackers", "open_loop", "warp_field", "--data", str(data), "--no-progress"]
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(SystemExit, match="--detector"):
        cli_main(args + ["--out", str(out), "--masks", "detected", "--detector", str(bad)])
    assert not data.exists() or not list(data.glob("*.mcap"))          # refused before generating
    assert cli_main(args + ["--out", str(out), "--masks", "recorded", "detected"]) in (0, None)
    doc = json.loads((out / "results.json").read_text())
    case = doc["cases"][0]
    assert case["case"]["rgb"] and case["case"]["name"].endswith("-s0-q-rgb")
    assert doc["columns"] == ["open_loop", "warp_field", "warp_field/detected", "ceiling"]
    from liquidtwin.evaluate.tracking import columns_for     # open loop reads no mask: one column, always
    assert columns_for(["open_loop", "warp_field"], ["detected"]) == ["open_loop", "warp_field/detected", "ceiling"]
    s = case["series"]
    rec_, det = s["warp_field"], s["warp_field/detected"]
    assert det["t_s"] == rec_["t_s"] == s["open_loop"]["t_s"]
    assert det["observed_px"] == rec_["observed_px"]               # the same reference masks
    assert det["iou"] != rec_["iou"]                               # but other corrections
    agree = case["detector"]
    assert len(agree["iou"]) == len(det["iou"]) and agree["observed_px"] == det["observed_px"]
    assert all(0.0 <= i <= 1.0 for i in agree["iou"])
    text = capsys.readouterr().out
    assert "warp det" in text and "detector masks vs recorded masks: mean IOU" in text
