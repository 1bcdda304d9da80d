"""Measurement realism: mask and pose noise, dropped frames, synthetic RGB of transparent liquid.

Every function takes an explicit ``numpy.random.Generator``; none touches global RNG state,
so one seed reproduces a whole recording.
"""

from ._common import SensorInputError
from .frames import dropped_frames
from .masks import MaskNoise, corrupt_mask
from .poses import PoseNoise, noisy_poses
from .rgb import RGBParams, synth_rgb
from .textures import KINDS as TEXTURE_KINDS
from .textures import TextureParams, random_texture, render_texture

__all__ = [
    "SensorInputError", "dropped_frames", "MaskNoise", "corrupt_mask", "PoseNoise", "noisy_poses",
    "RGBParams", "synth_rgb", "TEXTURE_KINDS", "TextureParams", "random_texture", "render_texture",
]
