"""Liquid labels from a thermal camera and thermal-to-colour registration (thesis §4.3.2, §4.3.5).

Labels: heated water is the hottest thing in view. Each frame is normalised to [0, 1] by its
own min and max (or by a given range — the thesis reuses the first liquid frame's range for
the frames before liquid appears) and thresholded at 0.6. Clean-up: the liquid warms the
table where it touched; pixels in a given table mask are dropped and so are connected
components smaller than ``min_area_px`` (8-connectivity).

Registration: a chessboard lit by a lamp is visible to both cameras — its dark squares absorb
more light and appear *brighter* in the thermal image (an inverted board, thesis footnote 3).
Corners found by OpenCV's findChessboardCorners in each image (refined by cornerSubPix)
give point pairs; an affine map thermal px → colour px is fitted to them by least squares.
It is exact only at the board's depth (the thesis pours at a fixed depth). Pixel
coordinates are OpenCV's: x right, y down, pixel centres at integers.
"""

from __future__ import annotations

import cv2
import numpy as np

from .flow import PerceptionInputError


class CalibrationError(ValueError):
    """No chessboard in an image, too few or degenerate point pairs, or a bad affine map."""


def _finite_2d(frame, name: str) -> np.ndarray:
    a = np.asarray(frame)
    if a.ndim != 2:
        raise PerceptionInputError(f"{name} must be an (H, W) image, got shape {a.shape}")
    if a.size == 0 or a.dtype == bool or not np.issubdtype(a.dtype, np.number):
        raise PerceptionInputError(f"{name} must be a non-empty numeric (H, W) image, got {a.shape} {a.dtype}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise PerceptionInputError(f"{name} has {int((~np.isfinite(a)).sum())} NaN/inf pixels; "
                                   "mask dead pixels before labelling")
    return a


def thermal_labels(frame, threshold: float = 0.6, table_mask=None, min_area_px: int = 10,
                   value_range=None) -> np.ndarray:
    """(H, W) thermal frame (any numeric dtype, e.g. °C float or raw uint16) → (H, W) bool liquid.

    ``value_range`` (lo, hi) in the frame's units replaces the per-frame min/max (for frames
    before liquid appears). A constant frame (or hi ≤ lo) has no liquid: all False.
    ``table_mask`` (H, W) bool: pixels that are table (or anything known not to be liquid).
    ``min_area_px``: components with fewer pixels are dropped (0 or 1 keeps all).
    """
    f = _finite_2d(frame, "thermal frame")
    if not (0.0 < float(threshold) < 1.0):
        raise PerceptionInputError(f"threshold is on the normalised [0, 1] scale; got {threshold}")
    if int(min_area_px) != min_area_px or min_area_px < 0:
        raise PerceptionInputError(f"min_area_px must be a whole number ≥ 0, got {min_area_px}")
    lo, hi = (f.min(), f.max()) if value_range is None else (float(v) for v in value_range)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise PerceptionInputError(f"value_range must be finite, got {value_range}")
    m = np.zeros(f.shape, bool) if table_mask is None else np.asarray(table_mask, bool)
    if m.shape != f.shape:
        raise PerceptionInputError(f"table_mask is {m.shape}, the frame {f.shape}")
    if not hi > lo:
        return np.zeros(f.shape, bool)
    labels = ((f - lo) / (hi - lo) >= threshold) & ~m
    if min_area_px > 1 and labels.any():
        _, comp, stats, _ = cv2.connectedComponentsWithStats(labels.astype(np.uint8), connectivity=8)
        keep = (stats[:, cv2.CC_STAT_AREA] >= min_area_px) & (np.arange(len(stats)) > 0)   # 0: background
        labels = keep[comp]
    return labels


def _grey_u8(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 3:
        if a.dtype != np.uint8:
            raise PerceptionInputError(f"a colour image must be uint8 RGB, got {a.dtype}")
        return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY)
    f = _finite_2d(a, "board image")
    lo, hi = np.percentile(f, [0.5, 99.5])      # a few hot or dead pixels do not squash the board
    if not hi > lo:
        raise CalibrationError("board image is constant: no chessboard visible (is the board heated?)")
    return np.round(np.clip((f - lo) * (255.0 / (hi - lo)), 0, 255)).astype(np.uint8)


def _canonical(corners: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Reorder a (rows·cols, 2) grid so rows run +x and successive rows +y (board within ±45°
    of upright): the two cameras then agree on corner order whatever OpenCV started from."""
    g = corners.reshape(rows, cols, 2)
    if cols == rows:
        along = g[0, -1] - g[0, 0]
        if abs(along[1]) > abs(along[0]):
            g = g.transpose(1, 0, 2)
    if (g[:, -1, 0] - g[:, 0, 0]).mean() < 0:
        g = g[:, ::-1]
    if (g[-1, :, 1] - g[0, :, 1]).mean() < 0:
        g = g[::-1]
    return np.ascontiguousarray(g.reshape(-1, 2))


_FLAG_SETS = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE, cv2.CALIB_CB_ADAPTIVE_THRESH, 0)


def _detect(grey: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """(cols·rows, 2) rough corners from findChessboardCorners, or None. Tries the image and
    its inverse with three flag sets (histogram equalisation hides a low-contrast heated board
    on a cold background), then all of that on a 2× upsampled image (squares under ~8 px)."""
    for up in (1, 2):
        g = grey if up == 1 else cv2.resize(grey, None, fx=2, fy=2, interpolation=cv2.INTER_LINEAR)
        for flags in _FLAG_SETS:
            for img in (g, 255 - g):
                found, corners = cv2.findChessboardCorners(img, (cols, rows), flags=flags)
                if found and corners is not None and len(corners) == cols * rows:
                    return (corners.reshape(-1, 2) + 0.5) / up - 0.5   # pixel centres at integers
    return None


def find_chessboard(image, pattern=(7, 5)) -> np.ndarray:
    """(N, 2) float32 inner corners in px (N = cols·rows), row by row, each row left to right.

    ``image``: (H, W, 3) uint8 RGB, or (H, W) thermal/grey of any numeric dtype (min–max to
    8 bits). ``pattern`` (cols, rows): inner corners per row and per column (OpenCV's
    patternSize); prefer cols ≠ rows. A heated board looks inverted (dark squares hot), the
    corners are the same: see ``_detect``. Refinement: cv2.cornerSubPix on the grey image, window
    0.9 corner spacings wide; a corner then > 0.15 spacings off the board's RANSAC homography
    is re-seeded there and refined again. CalibrationError when no board is found.
    """
    cols, rows = (int(v) for v in pattern)
    if cols < 2 or rows < 2:
        raise CalibrationError(f"pattern must have at least 2×2 inner corners, got {pattern}")
    grey = _grey_u8(image)
    corners = _detect(grey, cols, rows)
    if corners is None:
        raise CalibrationError(f"no {cols}×{rows} chessboard (inner corners) found in the "
                               f"{grey.shape[1]}×{grey.shape[0]} image; check the pattern size "
                               "and that the whole board, with a margin, is in view")
    pts = _canonical(corners, cols, rows)
    g2 = pts.reshape(rows, cols, 2)
    spacing = np.median(np.concatenate([np.linalg.norm(np.diff(g2, axis=1), axis=2).ravel(),
                                        np.linalg.norm(np.diff(g2, axis=0), axis=2).ravel()]))
    win = int(np.clip(0.45 * spacing, 2, 11))   # half-width: the window never reaches a neighbour
    refined = _subpix(grey, pts, win)
    # OpenCV's rough corner can sit half a square off (seen on blurred 8–9 px thermal squares),
    # beyond the reach of cornerSubPix: re-seed corners that leave the board's homography.
    idx = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2).astype(np.float32)
    hom, _ = cv2.findHomography(idx, refined, cv2.RANSAC, 0.15 * spacing)
    if hom is not None:
        pred = cv2.perspectiveTransform(idx.reshape(-1, 1, 2), hom).reshape(-1, 2)
        bad = np.linalg.norm(refined - pred, axis=1) > 0.15 * spacing
        if bad.any():
            refined[bad] = _subpix(grey, pred[bad], win)
    return refined.astype(np.float32)


def _subpix(grey: np.ndarray, pts: np.ndarray, win: int) -> np.ndarray:
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    seed = np.asarray(pts, np.float32).reshape(-1, 1, 2).copy()
    return cv2.cornerSubPix(grey, seed, (win, win), (-1, -1), crit).reshape(-1, 2)


def _points(p, name: str) -> np.ndarray:
    a = np.asarray(p, np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise CalibrationError(f"{name} must be (N, 2) pixel points, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise CalibrationError(f"{name} has NaN/inf points")
    return a


def apply_affine(affine, points) -> np.ndarray:
    """(2, 3) affine, (N, 2) px → (N, 2) float64 px: A[:, :2] @ p + A[:, 2]."""
    a = np.asarray(affine, np.float64)
    if a.shape != (2, 3):
        raise CalibrationError(f"an affine map is (2, 3), got {a.shape}")
    return _points(points, "points") @ a[:, :2].T + a[:, 2]


def fit_affine(src_pts, dst_pts) -> tuple[np.ndarray, float]:
    """Least-squares affine map src → dst: ((2, 3) float64, residual RMS in dst px).

    ``src_pts``, ``dst_pts``: (N, 2) px, N ≥ 3, in corresponding order, not all on one line.
    """
    src, dst = _points(src_pts, "src_pts"), _points(dst_pts, "dst_pts")
    if len(src) != len(dst):
        raise CalibrationError(f"src_pts has {len(src)} points, dst_pts {len(dst)}; they must pair up")
    if len(src) < 3:
        raise CalibrationError(f"an affine map needs at least 3 point pairs, got {len(src)}")
    sv = np.linalg.svd(src - src.mean(0), compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1.0):
        raise CalibrationError("the source points are collinear (or coincide); an affine map is undetermined")
    design = np.hstack([src, np.ones((len(src), 1))])        # (N, 3)
    sol, *_ = np.linalg.lstsq(design, dst, rcond=None)      # (3, 2), by SVD as in the thesis
    return sol.T, float(np.sqrt(np.mean(np.sum((design @ sol - dst) ** 2, axis=1))))


def register_thermal(thermal_board, colour_board, pattern) -> tuple[np.ndarray, float]:
    """Affine map thermal px → colour px from heated-chessboard views: ((2, 3), RMS colour px).

    ``thermal_board``: one (h, w) thermal image or a list of them; ``colour_board``: the
    matching (H, W, 3) uint8 RGB image(s), taken at the same moments. With several pairs all
    corners are pooled into one fit (board placed at the liquid's depth each time).
    """
    single = isinstance(thermal_board, np.ndarray) and np.asarray(thermal_board).ndim == 2
    th = [thermal_board] if single else list(thermal_board)
    co = [colour_board] if single else list(colour_board)
    if len(th) != len(co) or not th:
        raise CalibrationError(f"{len(th)} thermal and {len(co)} colour board images; give matching pairs")
    src, dst = [], []
    for i, (t, c) in enumerate(zip(th, co)):
        try:
            src.append(find_chessboard(t, pattern))
            dst.append(find_chessboard(c, pattern))
        except CalibrationError as e:
            raise CalibrationError(f"board pair {i}: {e}") from e
    return fit_affine(np.concatenate(src), np.concatenate(dst))


def warp_labels(labels, affine, out_shape) -> np.ndarray:
    """(h, w) bool thermal labels → (H, W) bool in colour px through the thermal → colour
    ``affine`` (2, 3) (nearest neighbour; outside the thermal view: False). ``out_shape`` (H, W)."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise PerceptionInputError(f"labels must be (h, w), got shape {lab.shape}")
    a = np.asarray(affine, np.float64)
    if a.shape != (2, 3) or not np.isfinite(a).all():
        raise CalibrationError(f"affine must be a finite (2, 3) map, got shape {a.shape}")
    if abs(np.linalg.det(a[:, :2])) < 1e-9:
        raise CalibrationError("affine map is singular (zero area); it cannot map images")
    h, w = (int(v) for v in out_shape[:2])
    out = cv2.warpAffine(lab.astype(np.uint8), a, (w, h), flags=cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool)


def _render(shape, board_to_px: np.ndarray, cols: int, rows: int, values, background: np.ndarray,
            ss: int = 4) -> np.ndarray:
    """Board (squares in board units, inner corners at u = 1…cols, v = 1…rows, a half-square
    margin) drawn over ``background`` (H, W), anti-aliased by ss×ss supersampling."""
    h, w = shape
    dark, light = values
    inv = np.linalg.inv(np.vstack([board_to_px, [0, 0, 1]]))[:2]
    off = (np.arange(ss) + 0.5) / ss - 0.5
    X, Y = np.meshgrid((np.arange(w)[:, None] + off).ravel(), (np.arange(h)[:, None] + off).ravel())
    u, v = (inv[i, 0] * X + inv[i, 1] * Y + inv[i, 2] for i in (0, 1))
    on_board = (u > -0.5) & (u < cols + 1.5) & (v > -0.5) & (v < rows + 1.5)
    in_squares = (u >= 0) & (u < cols + 1) & (v >= 0) & (v < rows + 1)
    is_dark = in_squares & ((np.floor(u) + np.floor(v)) % 2 == 0)
    img = np.where(on_board, np.where(is_dark, dark, light), np.repeat(np.repeat(background, ss, 0), ss, 1))
    return img.reshape(h, ss, w, ss).mean(axis=(1, 3))


def _inside(pts: np.ndarray, w: int, h: int, margin: float = 3.0) -> bool:
    return bool((pts.min(0) > margin).all() and (pts.max(0) < np.array([w, h]) - margin).all())


def synthetic_board_pair(rng: np.random.Generator, pattern=(7, 5), affine=None, colour_shape=(240, 320),
                         thermal_shape=(128, 160), noise: float = 0.02):
    """A lit chessboard seen by a colour and a thermal camera related by a known affine map.

    ``affine`` (2, 3): thermal px → colour px (default: the thermal view scaled 1.6× onto the
    colour image's centre). The board is placed at random (±10°, 45–60 % of the thermal width)
    so that it, with its margin, lies inside both images. Colour: dark squares ~30, light ~215
    grey on a textured background, (H, W, 3) uint8 RGB. Thermal: (h, w) float32 °C, dark
    squares hot (36 °C), light 30 °C, ambient ~22 °C, Gaussian blur σ 0.8 px (optics), lower
    resolution. ``noise``: Gaussian noise std as a fraction of each image's square contrast. →
    (colour, thermal, colour_corners (N, 2), thermal_corners (N, 2)): true corners, float64 px.
    """
    cols, rows = (int(v) for v in pattern)
    hc, wc = colour_shape
    ht, wt = thermal_shape
    if affine is None:
        affine = np.array([[1.6, 0, (wc - 1 - 1.6 * (wt - 1)) / 2], [0, 1.6, (hc - 1 - 1.6 * (ht - 1)) / 2]])
    A = np.vstack([np.asarray(affine, np.float64), [0, 0, 1]])
    grid = np.stack(np.meshgrid(np.arange(1.0, cols + 1), np.arange(1.0, rows + 1)), -1).reshape(-1, 2)
    outline = np.array([[-0.5, -0.5], [cols + 1.5, -0.5], [cols + 1.5, rows + 1.5], [-0.5, rows + 1.5]])
    for _ in range(200):
        side = rng.uniform(0.45, 0.6) * wt / (cols + 2)             # square size, thermal px
        ang = np.deg2rad(rng.uniform(-10, 10))
        c, s_ = np.cos(ang) * side, np.sin(ang) * side
        centre = np.array([wt, ht]) / 2 + rng.uniform(-0.15, 0.15, 2) * np.array([wt, ht])
        lin = np.array([[c, -s_], [s_, c]])
        b2t = np.hstack([lin, (centre - lin @ np.array([cols + 1, rows + 1]) / 2)[:, None]])
        b2c = (A @ np.vstack([b2t, [0, 0, 1]]))[:2]
        if _inside(outline @ b2t[:, :2].T + b2t[:, 2], wt, ht) and \
                _inside(outline @ b2c[:, :2].T + b2c[:, 2], wc, hc):
            break
    else:
        raise ValueError(f"the affine map puts no {cols}×{rows} board inside both the colour "
                         f"{wc}×{hc} and thermal {wt}×{ht} images")
    yy, xx = np.mgrid[0:hc, 0:wc] / max(hc, wc)
    bg_c = 120 + 30 * np.sin(6 * xx + rng.uniform(0, 6)) * np.cos(4 * yy + rng.uniform(0, 6))
    grey = _render((hc, wc), b2c, cols, rows, (30.0, 215.0), bg_c)
    tint = rng.uniform(0.9, 1.1, 3)
    colour = grey[..., None] * tint + rng.normal(0, noise * 185, (hc, wc, 3))
    colour = np.clip(np.round(colour), 0, 255).astype(np.uint8)
    yy, xx = np.mgrid[0:ht, 0:wt] / max(ht, wt)
    bg_t = 22 + 1.5 * xx + rng.uniform(-0.5, 0.5)
    thermal = _render((ht, wt), b2t, cols, rows, (36.0, 30.0), bg_t)
    thermal = cv2.GaussianBlur(thermal, (0, 0), 0.8) + rng.normal(0, noise * 6.0, (ht, wt))
    return (colour, thermal.astype(np.float32), grid @ b2c[:, :2].T + b2c[:, 2],
            grid @ b2t[:, :2].T + b2t[:, 2])
