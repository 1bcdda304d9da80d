"""Training and test data for the detectors: generated pours with synthetic RGB.

Each sequence is a recording from :func:`liquidtwin.generate.generate` (quick pour scenes,
``rgb=True``, perfect sensors so the recorded masks are the true visible liquid); textures,
lighting, camera placement, containers, fill and pour motion are drawn from the seed.
The split follows the thesis's robot dataset (§4.5.2): the test set uses containers never
seen in training — here both the source (``mug``) and the target (``pan``).

A third split, ``calib``, holds more pours of the *training* containers (fresh seeds, never
trained on): the detector's mask threshold is chosen there, since on the pours it was trained
on a network is over-confident and the F1-best threshold comes out too high.

A dataset directory holds ``train/NNN.mcap``, ``test/NNN.mcap`` and ``calib/NNN.mcap`` (+ truth
sidecars, unused here) and ``dataset.json`` recording the seeds and choices. Frames are loaded at network
resolution (``SIZE``): RGB by area interpolation, masks as "at least half the area liquid".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from ..generate import generate
from ..recordings import read_recording

SIZE = (160, 120)                       # network input (width, height): 320×240 halved
KINDS = ("pour_partial", "pour_hold", "pour_dump")
TRAIN = {"source": ("cup", "bottle"), "target": ("bowl", "fruit_bowl", "dog_dish")}
TEST = {"source": ("mug",), "target": ("pan",)}


@dataclass(frozen=True)
class Clip:
    """One sequence at network resolution: frames (T, H, W, 3) uint8 RGB, masks (T, H, W) bool."""

    name: str
    frames: np.ndarray
    masks: np.ndarray


def make_dataset(out, *, train: int = 12, test: int = 4, calib: int = 0, seed: int = 0,
                 progress: bool = True) -> dict:
    """Generate ``train`` + ``test`` + ``calib`` sequences into ``out``; returns the manifest.
    The calibration pours are drawn last, so adding them leaves the others unchanged; a pour
    already in ``out``'s manifest with the same draw (seed, scene, containers) is kept, not
    generated again (re-running with ``calib`` > 0 adds the calibration split only)."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    manifest = {"seed": seed, "size": list(SIZE), "train": [], "test": [], "calib": []}
    jobs = ([("train", i) for i in range(train)] + [("test", i) for i in range(test)]
            + [("calib", i) for i in range(calib)])
    made = out / "dataset.json"
    before = json.loads(made.read_text()) if made.is_file() else {}
    if before.get("seed") != seed:
        before = {}
    for split, i in tqdm(jobs, desc="generating", unit="seq", disable=not progress):
        pool = TEST if split == "test" else TRAIN
        choice = {"source": str(rng.choice(pool["source"])), "target": str(rng.choice(pool["target"])),
                  "fraction": float(rng.uniform(0.5, 1.0))}
        scene, s = str(rng.choice(KINDS)), int(rng.integers(2**31))
        path = out / split / f"{i:03d}.mcap"
        entry = {"file": f"{split}/{path.name}", "scene": scene, "seed": s, **choice}
        if not (entry in before.get(split, []) and path.is_file()):     # resume: same draw already made
            generate(scene, path, seed=s, quick=True, rgb=True, noise=False, choices=choice)
        manifest[split].append(entry)
        made.write_text(json.dumps(manifest, indent=2) + "\n")      # after every pour: resumable
    return manifest


def load_clip(path, size: tuple[int, int] = SIZE) -> Clip:
    """A recording's first camera as a :class:`Clip` at ``size`` = (width, height)."""
    rec = read_recording(path)
    if not rec.images:
        raise ValueError(f"{path} has no RGB images (generate it with rgb=True)")
    cam = sorted(rec.images)[0]
    t_img, imgs = rec.images[cam]
    t_mask, masks = rec.masks[cam]
    at = {int(t): k for k, t in enumerate(t_mask)}
    keep = [k for k, t in enumerate(t_img) if int(t) in at]
    frames = np.stack([cv2.resize(imgs[k], size, interpolation=cv2.INTER_AREA) for k in keep])
    labels = np.stack([cv2.resize(masks[at[int(t_img[k])]].astype(np.float32), size,
                                  interpolation=cv2.INTER_AREA) >= 0.5 for k in keep])
    return Clip(Path(path).stem, frames, labels)


def load_split(root, split: str, size: tuple[int, int] = SIZE) -> list[Clip]:
    """Every clip of ``split`` ("train", "test" or "calib") in a dataset directory (a split the
    dataset lacks: no clips)."""
    root = Path(root)
    manifest = root / "dataset.json"
    if not manifest.is_file():
        raise FileNotFoundError(f"{root} is not a perception dataset (no dataset.json); "
                                "make one with `liquidtwin perception data`")
    entries = json.loads(manifest.read_text()).get(split, [])
    return [load_clip(root / e["file"], size) for e in entries]
