"""Overlay pictures for a person to check the calibration at a glance."""

import cv2
import numpy as np

from pipeline.core.imageio import write_image

__all__ = ["overlay", "write_overlay", "write_sphere_overlays"]

GREEN, RED, YELLOW = (0, 255, 0), (255, 40, 40), (255, 220, 0)


def _display(image):
    """Grey or RGB float image -> uint8 RGB, stretched so the sphere's rim is visible."""
    img = np.asarray(image, np.float32)
    if img.ndim == 3:
        img = img.mean(-1)
    lo, hi = np.percentile(img, 1), np.percentile(img, 99.5)
    grey = np.clip((img - lo) / max(hi - lo, 1e-12), 0, 1) ** (1 / 2.2)
    return np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=-1)


def overlay(image, circles, highlights, flags):
    """Draw circles (green), highlight centres (numbered; red when flagged) on ``image``.

    image (H, W) or (H, W, C) float; circles: list of Circle; highlights (S, K, 2) pixels;
    flags {light: reason}. Returns uint8 (H, W, 3) RGB.
    """
    canvas = np.ascontiguousarray(_display(image))
    scale = max(1, canvas.shape[0] // 400)
    sub = 16  # cv2 draws sub-pixel positions in fixed point with 4 fractional bits
    for circle in circles:
        cv2.circle(canvas, (int(round(circle.cx * sub)), int(round(circle.cy * sub))),
                   int(round(circle.r * sub)), GREEN, scale, cv2.LINE_AA, 4)
        cv2.drawMarker(canvas, (int(round(circle.cx)), int(round(circle.cy))), GREEN, cv2.MARKER_CROSS,
                       6 * scale, scale)
    highlights = np.asarray(highlights, float)
    for spots in highlights.reshape(-1, highlights.shape[-2], 2) if highlights.size else []:
        for k, (x, y) in enumerate(spots):
            if not np.isfinite(x):
                continue
            colour = RED if k in flags else YELLOW
            cv2.drawMarker(canvas, (int(round(x)), int(round(y))), colour, cv2.MARKER_TILTED_CROSS,
                           8 * scale, scale)
            cv2.putText(canvas, str(k), (int(round(x)) + 4 * scale, int(round(y)) - 4 * scale),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale, colour, scale, cv2.LINE_AA)
    return canvas


def write_overlay(path, image, circles, highlights, flags):
    """Write :func:`overlay` as an 8-bit PNG (atomic)."""
    write_image(path, overlay(image, circles, highlights, flags), bits=8)


def _crop(image, circle, margin=0.15):
    """Window (row0, col0, view) around a circle with ``margin`` of its radius spare."""
    h, w = image.shape[:2]
    pad = circle.r * (1 + margin)
    r0, r1 = max(0, int(circle.cy - pad)), min(h, int(np.ceil(circle.cy + pad)) + 1)
    c0, c1 = max(0, int(circle.cx - pad)), min(w, int(np.ceil(circle.cx + pad)) + 1)
    return r0, c0, image[r0:r1, c0:c1]


def write_sphere_overlays(paths, image, circles, highlights, flags):
    """One close-up overlay per sphere: ``paths[s]`` shows ``circles[s]`` and, when given,
    ``highlights[s]`` (K, 2) pixels (None for a matte target). Circles are shifted copies, so
    the caller's stay untouched."""
    from dataclasses import replace
    for path, circle, spots in zip(paths, circles, highlights):
        r0, c0, view = _crop(image, circle)
        local = replace(circle, cx=circle.cx - c0, cy=circle.cy - r0)
        pts = np.zeros((1, 0, 2)) if spots is None else (np.asarray(spots) - [c0, r0])[None]
        write_overlay(path, view, [local], pts, flags)
