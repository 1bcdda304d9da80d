"""Sessions fed RGB instead of masks (issue 8): a real ``liquidtwin serve`` process, a pour
with containers the detector never saw in training streamed by ``liquidtwin-client stream
--masks rgb`` (images only, no masks), and the server's detector making the masks.

Checked: every image becomes an overlay whose observed mask is the shipped detector's own
output on those images (run here offline, frame by frame with its recurrent state), the
tracker runs closed loop on it, and an unknown mask source is refused clearly."""

from __future__ import annotations

import numpy as np
import pytest
from liquidtwin_proto import Error
from test_stream_e2e import run_stream

from liquidtwin.generate import generate
from liquidtwin.recordings import read_recording
from liquidtwin.session import OBSERVED_RGB, OVERLAP_RGB
from liquidtwin_client import Client, ServerError, load_replay


@pytest.fixture(scope="module")
def rgb_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rgb") / "pour.mcap"
    generate("pour_dump", path, seed=11, quick=True, rgb=True, noise=False,
             choices={"source": "mug", "target": "pan", "fraction": 0.9})
    return path


def _observed(msg) -> np.ndarray:
    img = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, 3)
    return np.all(img == OBSERVED_RGB, axis=2) | np.all(img == OVERLAP_RGB, axis=2)


def test_server_detects_liquid_in_rgb_and_tracks_with_it(module_servers, rgb_recording, tmp_path):
    from liquidtwin.perception.stream import StreamDetector
    server = module_servers.start()
    run = run_stream(server, rgb_recording, tmp_path, "rgb", "--rate", "max", "--masks", "rgb")
    rec = read_recording(rgb_recording)
    cam = next(iter(rec.images))
    stamps, images = rec.images[cam]
    overlays = {m.publish_time_ns: m.message for m in run["results"]["overlay"]}
    # every image was detected and its mask used (no mask was sent: they come from the detector)
    assert sorted(overlays) == [int(t) for t in stamps]
    assert run["summary"]["frames_answered"] == len(load_replay(rgb_recording).frames)
    # … by the shipped detector with its recurrent state carried from frame to frame
    offline = StreamDetector.from_file()
    agree = []
    for t, img in zip(stamps, images):
        agree.append(np.mean(offline(cam, img) == _observed(overlays[int(t)])))
    assert min(agree) > 0.999, min(agree)
    # and it found the liquid the recording's (perfect) masks show
    t_mask, truth = rec.masks[cam]
    wet = [k for k, m in enumerate(truth) if m.sum() >= 50]
    assert len(wet) >= 10
    iou = [np.sum(_observed(overlays[int(t_mask[k])]) & truth[k]) /
           np.sum(_observed(overlays[int(t_mask[k])]) | truth[k]) for k in wet]
    share = float(np.mean([truth[k].mean() for k in wet]))
    print(f"detector vs true masks on {len(wet)} wet frames: mean IOU {np.mean(iou):.3f} "
          f"(liquid share {share:.4f})")
    # a random mask as large as the truth scores about share / 2 (< 0.01 here); the shipped
    # detector measured 0.079 on this unseen-container pour (binary masks at its threshold —
    # its ranking quality, AUC vs the flow baseline, is checked in tests/server)
    assert np.mean(iou) > 4 * share
    assert run["summary"]["iou_frames"] == len(stamps)


def test_unknown_mask_source_is_refused(module_servers, rgb_recording):
    server = module_servers.start()
    spec = load_replay(rgb_recording).session_spec()
    spec.mask_source = "thermal"
    with Client(server.endpoint) as client:
        with pytest.raises(ServerError) as bad:
            client.create_session(spec, timeout=60)
    assert bad.value.code == Error.BAD_REQUEST and "mask_source" in str(bad.value)
