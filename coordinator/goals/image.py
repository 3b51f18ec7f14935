"""Input image and background subtraction (paper 4.1): RGB uint8 (H, W, 3), row 0 at the top, and an
optional alpha (H, W) marking transparent background. Colour distances are CIE76 Delta E in Lab."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .model import GoalError

NAMED_COLORS = {"white": (255, 255, 255), "black": (0, 0, 0), "red": (255, 0, 0), "green": (0, 255, 0)}
NAMED_COLORS |= {"blue": (0, 0, 255), "gray": (128, 128, 128), "grey": (128, 128, 128)}
_MAGIC = (b"\x89PNG", b"\xff\xd8", b"BM", b"II*\x00", b"MM\x00*")
BG_TOLERANCE = 12.0  # Delta E: colours closer than this to the background are background


@dataclass
class Foreground:
    """Foreground mask and how it was found: 'alpha', 'color' (explicit) or 'border' (automatic)."""

    mask: np.ndarray
    source: str
    work: np.ndarray  # the RGB image the decision was made on (denoised for noisy inputs)
    background: tuple[int, int, int] | None
    tolerance: float


def load_image(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a PNG, JPEG, BMP or TIFF file: (RGB uint8, alpha uint8 or None). Raises GoalError."""
    p = Path(path)
    if not p.exists():
        raise GoalError(f"no such file: {p}")
    if p.is_dir():
        raise GoalError(f"{p} is a directory, not an image")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise GoalError(f"cannot read {p}: {exc.strerror or exc}") from None
    if not data.startswith(_MAGIC):
        raise GoalError(f"cannot read {p}: not a PNG, JPEG, BMP or TIFF image")
    logging = cv2.utils.logging  # quiet: a damaged file is our one-line error, not OpenCV's warning
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    finally:
        logging.setLogLevel(level)
    if raw is None or raw.size == 0:
        raise GoalError(f"cannot read {p}: the image data is damaged or unsupported")
    return split_channels(raw, bgr=True)


def split_channels(raw: np.ndarray, *, bgr: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Any gray, RGB or RGBA array (uint8, uint16 or float in [0, 1]) to (RGB uint8, alpha or None)."""
    a = np.asarray(raw)
    if a.dtype == np.uint16:
        a = (a.astype(np.float64) / 257.0).round()
    elif a.dtype.kind == "f":
        a = np.clip(a, 0.0, 1.0) * 255.0
    elif a.dtype == bool:
        a = a * 255
    a = np.clip(a, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4) or min(a.shape[:2]) < 1:
        raise GoalError(f"an image must be H x W with 1 to 4 channels, not shape {tuple(np.shape(raw))}")
    alpha = None
    if a.shape[2] in (2, 4):
        alpha = a[:, :, -1].copy()
        a = a[:, :, :-1]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    elif bgr:
        a = a[:, :, ::-1]
    return np.ascontiguousarray(a), alpha


def parse_color(text: str | tuple[int, int, int] | list[int]) -> tuple[int, int, int]:
    """'#rrggbb', 'r,g,b' or a name (white, black, ...) to an RGB tuple. Raises GoalError."""
    if not isinstance(text, str):
        vals = [int(v) for v in text]
    else:
        t = text.strip().lower()
        if t in NAMED_COLORS:
            return NAMED_COLORS[t]
        try:
            if t.startswith("#") and len(t) == 7:
                vals = [int(t[i : i + 2], 16) for i in (1, 3, 5)]
            else:
                vals = [int(v) for v in t.split(",")]
        except ValueError:
            vals = []
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise GoalError(f"bad colour {text!r}: use #rrggbb, r,g,b (0-255) or a name such as white")
    return (vals[0], vals[1], vals[2])


def to_lab(rgb: np.ndarray, *, precise: bool = False) -> np.ndarray:
    """RGB uint8 (..., 3) to float32 CIE Lab: by default OpenCV's 8-bit conversion (0.4 units, far below the
    segmentation's tolerances), precise=True in floating point (for goal colours)."""
    if precise:
        f = np.asarray(rgb, dtype=np.float32).reshape(-1, 1, 3) / 255.0
        return cv2.cvtColor(f, cv2.COLOR_RGB2Lab).reshape(np.shape(rgb))
    a = np.ascontiguousarray(np.asarray(rgb, dtype=np.uint8).reshape(-1, 1, 3))
    lab = cv2.cvtColor(a, cv2.COLOR_RGB2Lab).reshape(-1, 3).astype(np.float32)
    lab *= np.array([100.0 / 255.0, 1.0, 1.0], np.float32)
    lab -= np.array([0.0, 128.0, 128.0], np.float32)
    return lab.reshape(np.shape(rgb))


def lab_to_rgb(lab: np.ndarray) -> np.ndarray:
    """Float CIE Lab (..., 3) to RGB uint8."""
    a = np.asarray(lab, dtype=np.float32).reshape(-1, 1, 3)
    rgb = cv2.cvtColor(a, cv2.COLOR_Lab2RGB).reshape(np.shape(lab))
    return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)


def lab_sums(lab: np.ndarray, groups: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group 0..n-1: the sum of the Lab colours (rows of lab) and their number (groups: per row, -1 to skip)."""
    sel = groups >= 0
    cnt = np.bincount(groups[sel], minlength=n)
    sums = np.stack([np.bincount(groups[sel], lab[sel, c], n) for c in range(3)], axis=1)
    return sums, cnt


def _border_model(lab: np.ndarray, tol: float) -> tuple[np.ndarray, float, np.ndarray]:
    """A quadratic Lab background fitted to the border's dominant colour: (Lab per pixel, noise sigma, colour)."""
    h, w = lab.shape[:2]
    band = max(1, round(0.01 * min(h, w)))  # the border: a band of 1 % of the shorter side
    border = np.zeros((h, w), bool)
    border[:band], border[-band:], border[:, :band], border[:, -band:] = True, True, True, True
    ys, xs = np.nonzero(border)
    vals = lab[ys, xs].astype(np.float64)
    k = np.floor((vals + np.array([0.0, 128.0, 128.0])) / 8.0).astype(np.int64)
    _, inv, counts = np.unique((k[:, 0] * 64 + k[:, 1]) * 64 + k[:, 2], return_inverse=True, return_counts=True)
    dominant = vals[inv.reshape(-1) == np.argmax(counts)].mean(axis=0)
    resid = np.linalg.norm(vals - dominant, axis=1)
    inliers = resid < 2.0 * tol
    if float(np.max(resid[inliers])) < 0.5:  # a flat background colour
        return np.broadcast_to(dominant, lab.shape), 0.0, dominant
    u, v = xs / max(w - 1, 1) - 0.5, ys / max(h - 1, 1) - 0.5  # the border pixels, the image centred on 0
    terms = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=1)
    coef = np.zeros((terms.shape[1], 3))
    coef[0] = dominant
    sigma = 0.0
    for _ in range(4):
        if inliers.sum() >= 4 * terms.shape[1]:
            coef, *_ = np.linalg.lstsq(terms[inliers], vals[inliers], rcond=None)
        resid = np.linalg.norm(vals - terms @ coef, axis=1)
        sigma = 1.4826 * float(np.median(resid[inliers])) if inliers.any() else 0.0
        inliers = resid < max(2.0 * tol, 4.0 * sigma)
    x = (np.arange(w) / max(w - 1, 1) - 0.5)[None, :, None]
    y = (np.arange(h) / max(h - 1, 1) - 0.5)[:, None, None]
    c = coef[:, None, None, :]
    model = c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y
    return model, sigma, dominant


def foreground_mask(
    rgb: np.ndarray, alpha: np.ndarray | None = None, *, background: str | tuple[int, int, int] | None = None
) -> Foreground:
    """Background subtraction: transparent pixels, those within BG_TOLERANCE of an explicit background
    colour, or else of the dominant border colour (a smooth gradient, tolerance >= 4 sigma of its noise)."""
    rgb = np.asarray(rgb, dtype=np.uint8)
    opaque = alpha >= 128 if alpha is not None and int(alpha.min()) < 255 else None
    if background is not None:
        color = parse_color(background)
        diff = np.linalg.norm(to_lab(rgb) - to_lab(np.array(color, np.uint8)), axis=-1)
        mask = diff > BG_TOLERANCE if opaque is None else (diff > BG_TOLERANCE) & opaque
        return Foreground(mask, "color", rgb, color, BG_TOLERANCE)
    if opaque is not None:
        return Foreground(opaque, "alpha", rgb, None, BG_TOLERANCE)
    work, lab = rgb, to_lab(rgb)
    model, sigma, dominant = _border_model(lab, BG_TOLERANCE)
    if sigma > 2.0:  # a noisy photo: decide on a denoised copy
        work = cv2.medianBlur(rgb, 5)
        lab = to_lab(work)
        model, sigma, dominant = _border_model(lab, BG_TOLERANCE)
    tol = max(BG_TOLERANCE, 4.0 * sigma)
    mask = np.linalg.norm(lab - model, axis=-1) > tol
    if sigma > 1.0:
        mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    bg = tuple(int(v) for v in lab_to_rgb(dominant.astype(np.float32)))
    return Foreground(mask, "border", work, bg, tol)  # type: ignore[arg-type]  # bg: three ints, typed as tuple[int, ...]
