"""`--data` caches of the generated benchmarks: a recording is reused only when its generation
finished and the current generator world wrote it; an older world's recordings are redone."""

import json

from liquidtwin.evaluate.benchmark import Case, cached, ensure, missing_from, recording_path
from liquidtwin.generate.generator import WORLD_VERSION


def _fake(dirpath, name, world_version=WORLD_VERSION, case=True, truth=True):
    rec = dirpath / f"{name}.mcap"
    rec.write_bytes(b"")
    if truth:
        body = {"version": 1} if world_version is None else {"version": 1, "world_version": world_version}
        rec.with_suffix(".truth.json").write_text(json.dumps(body))
    if case:
        rec.with_suffix(".case.json").write_text("{}")
    return rec


def test_only_finished_recordings_of_this_world_are_reused(tmp_path, capsys):
    paths = [_fake(tmp_path, "current"), _fake(tmp_path, "older", WORLD_VERSION - 1),
             _fake(tmp_path, "unversioned", None), _fake(tmp_path, "unfinished", case=False),
             _fake(tmp_path, "no-truth", truth=False)]
    (tmp_path / "corrupt.truth.json").write_text("{not json")
    paths.append(_fake(tmp_path, "corrupt", truth=False))
    assert [cached(p) for p in paths] == [True, False, False, False, False, False]
    assert missing_from(paths) == [1, 2, 3, 4, 5]
    out = capsys.readouterr().out
    assert "4 cached recording(s)" in out and "older generator world" in out     # unfinished is not stale


def test_ensure_generates_an_older_worlds_recording_again(tmp_path):
    case = Case("cup", 0.3, "dump", 0, 3, True)
    path = recording_path(tmp_path, case)
    assert ensure([case], tmp_path, progress=False) == [path] and cached(path)
    truth = path.with_suffix(".truth.json")
    first = json.loads(truth.read_text())
    assert first["world_version"] == WORLD_VERSION
    truth.write_text(json.dumps(first | {"world_version": WORLD_VERSION - 1}))
    stamp = path.stat().st_mtime_ns
    ensure([case], tmp_path, progress=False)
    assert cached(path) and path.stat().st_mtime_ns > stamp
    again = json.loads(truth.read_text())
    assert again == first                                   # deterministic: the same recording's truth
    stamp = path.stat().st_mtime_ns
    ensure([case], tmp_path, progress=False)                # current: reused, not redone
    assert path.stat().st_mtime_ns == stamp
