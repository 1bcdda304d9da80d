"""Network input types (thesis §4.4.2): RGB, grey, optical flow, and image + flow fused.

``INPUTS`` maps an input name to its channel groups: one group for a single input, two
(image, flow) for the fused ones. Early fusion feeds the groups' channels concatenated to
one input block; late fusion feeds each group to its own block (see :mod:`.nets`).

:class:`FrameEncoder` turns a stream of RGB frames into network inputs — it keeps the
previous grey frame for the flow, so a server session holds one per camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from .flow import PerceptionInputError, check_rgb, flow_planes

INPUTS: dict[str, tuple[int, ...]] = {
    "rgb": (3,), "grey": (1,), "flow": (3,),
    "rgb_flow": (3, 3), "grey_flow": (1, 3),
}
FUSIONS = ("early", "late")

AUGMENTS = ("flip", "colour")
AUGMENT_HELP = ("training augmentation: flip (mirror left-right, the flow's angle mirrored too), colour (random "
                "gain, shift and RGB channel order of the image planes), flip,colour, or none (default: none)")


def parse_augment(text: str) -> str:
    """Canonical augmentation string ("", "flip", "colour", "flip,colour"); clear error otherwise."""
    parts = [a.strip() for a in (text or "").split(",") if a.strip() and a.strip() != "none"]
    bad = sorted(set(parts) - set(AUGMENTS))
    if bad:
        raise ValueError(f"unknown augmentation {', '.join(bad)}; choose from {', '.join(AUGMENTS)} "
                         "(comma-separated) or none")
    return ",".join(a for a in AUGMENTS if a in parts)


def check_input(input_type: str, fusion: str = "early") -> tuple[int, ...]:
    """Channel groups of ``input_type``; clear error for unknown names."""
    if input_type not in INPUTS:
        raise PerceptionInputError(f"unknown input type {input_type!r}; choose from {sorted(INPUTS)}")
    if fusion not in FUSIONS:
        raise PerceptionInputError(f"unknown fusion {fusion!r}; choose from {FUSIONS}")
    return INPUTS[input_type]


def needs_flow(input_type: str) -> bool:
    return "flow" in input_type


class FrameEncoder:
    """RGB frames → (C, H, W) float32 network inputs at ``size`` = (width, height).

    Channels in order: image (RGB 3 or grey 1, in [0, 1]) then flow (3, see :mod:`.flow`).
    Frames are resized first (area interpolation), so flow is computed at network resolution.
    """

    def __init__(self, input_type: str, size: tuple[int, int] | None = None):
        check_input(input_type)
        self.input_type = input_type
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self._prev: np.ndarray | None = None

    def reset(self) -> None:
        self._prev = None

    def __call__(self, image) -> np.ndarray:
        rgb = check_rgb(image)
        if self.size is not None and (rgb.shape[1], rgb.shape[0]) != self.size:
            rgb = cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if self._prev is not None and self._prev.shape != grey.shape:
            raise PerceptionInputError(f"frame size changed mid-stream: {self._prev.shape[::-1]} → "
                                       f"{grey.shape[::-1]}; reset the stream first")
        planes = []
        if self.input_type.startswith("rgb"):
            planes.append(rgb.transpose(2, 0, 1).astype(np.float32) / 255.0)
        elif self.input_type.startswith("grey"):
            planes.append(grey[None].astype(np.float32) / 255.0)
        if needs_flow(self.input_type):
            planes.append(flow_planes(self._prev, grey))
        self._prev = grey
        return np.concatenate(planes, axis=0)

    def sequence(self, frames) -> np.ndarray:
        """(T, C, H, W) inputs of a whole sequence (resets the stream first)."""
        self.reset()
        return np.stack([self(f) for f in frames])
