"""Synthetic RGB frames of transparent liquid for training and testing perception.

A frame is: a procedural background (:mod:`.textures`) → opaque objects painted in their
colours with dome shading → transparent liquid that refracts (displaces) what is behind it,
tints with thickness, reflects and sparkles → camera: exposure, white balance, vignetting,
lighting gradient, blur, signal-dependent noise, JPEG artefacts.

For a video, sample ``RGBParams`` (it includes the background's own seed) once per recording
and pass it to every frame: the scene then stays put and only sensor noise changes. Passing
``background=render_texture(params.texture, H, W)`` as well saves re-rendering the texture
(5–15 ms at 640×480).

Speed (640×480, shared 2-core box): ~25–32 ms per frame, ~45 ms when liquid covers most
of it. About half of that is first-touch page faults of numpy temporaries: a generation
process that sets glibc's ``MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=268435456``
renders the same frames in ~13–19 ms (~24 ms with liquid everywhere).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import cv2
import numpy as np

from ._common import SensorInputError, check_generator, check_image_shape, fast_gaussian
from ._inputs import check_maps, color_table
from ._paint import paint_liquid, paint_objects
from .textures import TextureParams, texture_planes


@dataclass(frozen=True)
class RGBParams:
    """Appearance of one recording. Ranges are those of :meth:`sample`; colours RGB in [0, 1];
    directions in the image frame (x right, y down, z towards the camera).

    texture:             background texture
    object_roundness_px: objects' shading rolls off over this distance to the silhouette, 4–30 px
    object_texture:      relative amplitude of the objects' fine surface texture, 0–0.12
    object_gloss:        objects' highlight strength, 0–0.4
    light_dir:           unit vector towards the key light, elevation 25–80°
    ambient:             share of ambient light on objects, 0.3–0.7
    light_color:         key light / highlight colour (near white)
    refraction_px:       background displacement where the liquid surface is steepest, 2–12 px
    surface_sigma_px:    smoothing of the thickness field into a surface, 1.5–4 px
    edge_lift:           roundness of the liquid's edge relative to its mean thickness, 0.3–1.2
    normal_tilt:         how strongly surface slope tilts the normal (shading only), 0.5–1.5
    absorption:          (3,) per-channel absorption per unit normalised thickness, 0–0.35
    specular, shininess: Blinn–Phong highlight strength 0.2–1 and exponent 20–200
    fresnel:             reflectance at normal incidence, 0.02–0.1
    rim:                 brightness added along the liquid's edges, 0.05–0.4
    env_color:           colour of the reflected environment
    liquid_blur_px:      blur of what is seen through the liquid, 0–1.2 px
    thickness_ref:       thickness (input units) that counts as 1; None = mean over the mask
                         per frame (set it for videos whose liquid amount changes)
    exposure:            overall gain, 0.7–1.4
    white_balance:       (3,) channel gains, 0.85–1.15 (green = 1)
    vignette:            brightness lost in the corners, 0–0.45
    light_gradient:      (2,) relative brightness change across the width / height, ±0.3
    noise_read:          std of signal-independent noise, 0.002–0.02
    noise_shot:          noise variance per unit intensity, 0–0.001
    blur_px:             Gaussian defocus std, 0 (half the time) or 0.3–1.5 px
    motion_px, motion_angle_rad: motion blur length (0 70 % of the time, else 2–8 px) and angle
    jpeg_quality:        0 = no compression (30 %), else 45–95
    """

    texture: TextureParams = field(default_factory=TextureParams)
    object_roundness_px: float = 12.0
    object_texture: float = 0.05
    object_gloss: float = 0.2
    light_dir: tuple = (0.35, -0.45, 0.82)
    ambient: float = 0.45
    light_color: tuple = (1.0, 1.0, 1.0)
    refraction_px: float = 6.0
    surface_sigma_px: float = 2.5
    edge_lift: float = 0.6
    normal_tilt: float = 1.0
    absorption: tuple = (0.15, 0.07, 0.04)
    specular: float = 0.6
    shininess: float = 60.0
    fresnel: float = 0.05
    rim: float = 0.2
    env_color: tuple = (0.9, 0.92, 0.95)
    liquid_blur_px: float = 0.5
    thickness_ref: float | None = None
    exposure: float = 1.0
    white_balance: tuple = (1.0, 1.0, 1.0)
    vignette: float = 0.2
    light_gradient: tuple = (0.0, 0.0)
    noise_read: float = 0.006
    noise_shot: float = 0.0003
    blur_px: float = 0.0
    motion_px: float = 0.0
    motion_angle_rad: float = 0.0
    jpeg_quality: int = 0

    def __post_init__(self):
        for name, n in _VECTORS:
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (n,) or not np.isfinite(v).all():
                raise SensorInputError(
                    f"RGBParams.{name} must be {n} finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        if np.linalg.norm(self.light_dir) < 1e-6:
            raise SensorInputError("RGBParams.light_dir must not be zero")
        for name in _SCALARS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not 0 <= v < math.inf:
                raise SensorInputError(f"RGBParams.{name} must be a finite number ≥ 0, got {v!r}")
        if self.object_roundness_px < 1 or self.surface_sigma_px < 0.3:
            raise SensorInputError(
                "RGBParams.object_roundness_px must be ≥ 1 px and surface_sigma_px ≥ 0.3 px")
        ref = self.thickness_ref
        if ref is not None and not (isinstance(ref, numbers.Real) and 0 < ref < math.inf):
            raise SensorInputError(f"RGBParams.thickness_ref must be None or > 0, got {ref!r}")
        if not (self.jpeg_quality == 0 or 1 <= int(self.jpeg_quality) <= 100):
            raise SensorInputError(
                f"RGBParams.jpeg_quality must be 0 (off) or 1–100, got {self.jpeg_quality!r}")

    @staticmethod
    def sample(rng: np.random.Generator) -> "RGBParams":
        """Random appearance within the documented ranges (domain randomisation)."""
        u = check_generator(rng).uniform
        az, el = u(0, 2 * math.pi), math.radians(u(25, 80))
        warm = u(-0.1, 0.1)
        if rng.random() < 0.7:   # water-like: red absorbed most → cyan tint
            absorption = np.array([1.0, 0.5, 0.3]) * u(0.02, 0.35)
        else:                    # coloured drink
            absorption = rng.uniform(0.0, 0.35, 3)
        wb = rng.uniform(0.85, 1.15, 3)
        env = np.clip(u(0.7, 1.0) * (1 + rng.uniform(-0.05, 0.05, 3)), 0, 1)
        return RGBParams(
            texture=TextureParams.sample(rng), object_roundness_px=u(4, 30),
            object_texture=u(0, 0.12), object_gloss=u(0, 0.4),
            light_dir=(math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)),
            ambient=u(0.3, 0.7), light_color=(1 + warm, 1.0, 1 - warm), refraction_px=u(2, 12),
            surface_sigma_px=u(1.5, 4), edge_lift=u(0.3, 1.2), normal_tilt=u(0.5, 1.5),
            absorption=tuple(absorption), specular=u(0.2, 1.0),
            shininess=math.exp(u(math.log(20), math.log(200))), fresnel=u(0.02, 0.1),
            rim=u(0.05, 0.4), env_color=tuple(env), liquid_blur_px=u(0, 1.2),
            exposure=math.exp(u(math.log(0.7), math.log(1.4))),
            white_balance=(wb[0] / wb[1], 1.0, wb[2] / wb[1]), vignette=u(0, 0.45),
            light_gradient=tuple(rng.uniform(-0.3, 0.3, 2)), noise_read=u(0.002, 0.02),
            noise_shot=u(0, 0.001), blur_px=0.0 if rng.random() < 0.5 else u(0.3, 1.5),
            motion_px=0.0 if rng.random() < 0.7 else u(2, 8), motion_angle_rad=u(0, math.pi),
            jpeg_quality=0 if rng.random() < 0.3 else int(rng.integers(45, 96)))


_VECTORS = (("light_dir", 3), ("light_color", 3), ("absorption", 3), ("env_color", 3),
            ("white_balance", 3), ("light_gradient", 2))
_SCALARS = ("object_roundness_px", "object_texture", "object_gloss", "ambient", "refraction_px",
            "surface_sigma_px", "edge_lift", "normal_tilt", "specular", "shininess", "fresnel",
            "rim", "liquid_blur_px", "exposure", "vignette", "noise_read", "noise_shot",
            "blur_px", "motion_px", "motion_angle_rad")


def synth_rgb(rng: np.random.Generator, *, liquid_thickness: np.ndarray, liquid_mask: np.ndarray,
              labels: np.ndarray, object_colors, background: np.ndarray | None = None,
              params: RGBParams | None = None) -> np.ndarray:
    """One synthetic camera frame (H, W, 3) uint8 RGB.

    rng:              numpy Generator: draws ``params`` when None, then the sensor noise
                      (same seed and inputs → identical frame).
    liquid_thickness: (H, W) float or int ≥ 0, any unit (particle count or path length per
                      pixel); only its shape within the mask matters (see thickness_ref).
    liquid_mask:      (H, W) bool, True where liquid is visible (in front of everything).
    labels:           (H, W) int, 0 = background, k ≥ 1 = object k.
    object_colors:    RGB albedo per label: a (K, 3) array (row k−1 is label k) or a mapping
                      {label: (r, g, b)}; float values in [0, 1] or integer values 0–255.
    background:       optional (H, W, 3) uint8 or float in [0, 1]; default the params' texture.
    params:           appearance; default ``RGBParams.sample(rng)``.
    """
    rng = check_generator(rng)
    thickness, mask, labels = check_maps(liquid_thickness, liquid_mask, labels)
    h, w = mask.shape
    table = color_table(object_colors, labels)
    if params is None:
        params = RGBParams.sample(rng)
    elif not isinstance(params, RGBParams):
        raise SensorInputError(f"params must be an RGBParams, got {type(params).__name__}")
    if background is None:
        bg = texture_planes(params.texture, h, w)
    else:
        bg = _as_planes(background, h, w)
    paint_objects(bg, labels, table, params)
    paint_liquid(bg, thickness, mask, params)
    return _camera(bg, rng, params)


def _as_planes(background, h: int, w: int) -> np.ndarray:
    """(H, W, 3) uint8 or float [0, 1] image → (3, H, W) float32 planes (a new array)."""
    b = np.asarray(background)
    check_image_shape("background", b, (h, w, 3))
    if b.dtype == np.uint8:
        planes = b.transpose(2, 0, 1).astype(np.float32)
        planes *= np.float32(1.0 / 255.0)
        return planes
    if b.dtype.kind != "f" or not (b.min() >= 0 and b.max() <= 1):   # NaN fails both
        raise SensorInputError(f"background must be uint8 or float in [0, 1], got {b.dtype}")
    return b.transpose(2, 0, 1).astype(np.float32, order="C")


def _camera(img: np.ndarray, rng: np.random.Generator, p: RGBParams) -> np.ndarray:
    """(3, H, W) float planes → optics blur → exposure, white balance, vignetting, light
    gradient → Poisson–Gaussian noise → (H, W, 3) uint8 → JPEG round trip."""
    h, w = img.shape[1:]
    kernel = _motion_kernel(p.motion_px, p.motion_angle_rad) if p.motion_px >= 1 else None
    xn = np.linspace(-1.0, 1.0, w, dtype=np.float32)
    yn = np.linspace(-1.0, 1.0, h, dtype=np.float32)[:, None]
    gain = (1.0 - 0.5 * p.vignette * (xn * xn + yn * yn)) * (
        1.0 + 0.5 * p.light_gradient[0] * xn + 0.5 * p.light_gradient[1] * yn)
    wb = p.exposure * np.asarray(p.white_balance, np.float32)
    noise = fast_gaussian(rng, img.shape)
    planes = []
    for c in range(3):
        x = img[c]
        if p.blur_px > 0:
            x = cv2.GaussianBlur(x, (0, 0), p.blur_px)
        if kernel is not None:
            x = cv2.filter2D(x, -1, kernel, borderType=cv2.BORDER_REFLECT)
        x = x * gain
        x *= wb[c]
        np.clip(x, 0.0, 1.0, out=x)
        sigma = x * p.noise_shot          # Poisson–Gaussian: var = read² + shot · intensity
        sigma += p.noise_read ** 2
        np.sqrt(sigma, out=sigma)
        sigma *= noise[c]
        x += sigma
        planes.append(cv2.convertScaleAbs(np.clip(x, 0.0, 1.0, out=x), alpha=255.0))
    out = cv2.merge(planes)
    if p.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(out, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, int(p.jpeg_quality)])
        out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out


def _motion_kernel(length_px: float, angle: float) -> np.ndarray:
    """Normalised line kernel of ``length_px`` px at ``angle`` rad (odd size)."""
    n = int(math.ceil(length_px)) | 1
    k = np.zeros((n, n), np.float32)
    c, d = n // 2, 0.5 * length_px
    dx, dy = d * math.cos(angle), d * math.sin(angle)
    cv2.line(k, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1, cv2.LINE_AA)
    return k / k.sum()
