"""Procedural textures for the tank: painted concrete, fouling and the floor.

A feature detector needs something to find, as on a real tank wall: the paint
carries low-frequency blotches, formwork seams every metre, rust streaks running
down from fixings, a few faint scratches and a little grit. Everything is drawn from a seeded
generator, so the same seed gives the same pixels (rendering tests rely on it).

How rough the paint looks decides where keypoints fall. The paper's Fig. 4A shows them concentrated on
"the ladder feet and edges of the window and frame, and the two visible edges of the corner"
(Ruediger & Banerjee, Sec. IV.B), so its painted walls gave the detector little. Our first texture
(grit of 12 levels per 2 mm texel, 60 scratches at 70 and 230 levels) made keypoints fall everywhere:
measured on rendered frames of the paper's path, ORB put 24 % of its keypoints within 5 cm of those
features, which cover 27 % of the image, and GFTT 4 %. The defaults below (grit 3 levels, 10 faint
scratches) give ORB 53 % and GFTT 36 % there (tests/test_frontend_rendered.py). The old look is
``TextureParams.rough()``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class TextureParams:
    """Size and look of the procedural textures; ``size_px`` covers ``tile_m`` metres."""

    size_px: int = 1024
    tile_m: float = 2.0
    seam_spacing_m: float = 1.0
    rust_streaks: int = 7
    scratches: int = 10
    scratch_contrast: float = 40.0  # levels above or below the paint (0 to 255)
    grit_sigma: float = 3.0  # levels of per-texel grit
    seed: int = 7

    @classmethod
    def rough(cls) -> TextureParams:
        """The first, rougher paint (module docstring): keypoints everywhere on the walls."""
        return cls(scratches=60, scratch_contrast=-1.0, grit_sigma=12.0)


def _noise(rng: np.random.Generator, size: int, octaves=(4, 16, 64, 256), weights=(0.4, 0.25, 0.2, 0.15)):
    """Tileable multi-octave value noise in [0, 1] (wrap-around upsampling keeps it tileable)."""
    out = np.zeros((size, size), np.float32)
    for cells, weight in zip(octaves, weights, strict=True):
        grid = rng.random((cells, cells)).astype(np.float32)
        if size % cells == 0:
            # two wrapped cells around the grid are all the cubic kernel reaches: the same pixels as
            # upsampling a 3 x 3 tiling and keeping its middle, at a ninth of the work at fine octaves
            pad, scale = 2, size // cells
            padded = np.pad(grid, pad, mode="wrap")
            span = (cells + 2 * pad) * scale
            up = cv2.resize(padded, (span, span), interpolation=cv2.INTER_CUBIC)
            out += weight * up[pad * scale : pad * scale + size, pad * scale : pad * scale + size]
        else:
            tiled = np.tile(grid, (3, 3))
            up = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
            out += weight * up[size : 2 * size, size : 2 * size]
    return np.clip(out, 0.0, 1.0)


def concrete_texture(params: TextureParams | None = None) -> np.ndarray:
    """Painted concrete wall, ``(size, size, 3)`` uint8 RGB."""
    p = params or TextureParams()
    rng = np.random.default_rng(p.seed)
    n = p.size_px
    px_per_m = n / p.tile_m
    base = np.array([178, 182, 176], np.float32)  # pale grey-green pool paint
    shade = _noise(rng, n)
    image = base[None, None, :] * (0.6 + 0.6 * shade[..., None])
    grit = rng.normal(0.0, p.grit_sigma, (n, n, 1)).astype(np.float32)
    image += grit
    # formwork seams: dark lines every seam_spacing_m, both directions
    spacing = round(p.seam_spacing_m * px_per_m)
    for k in range(0, n, spacing):
        image[max(k - 2, 0) : k + 2, :, :] *= 0.55
        image[:, max(k - 2, 0) : k + 2, :] *= 0.55
    # rust streaks: orange-brown, strongest at a fixing and fading downwards
    rust = np.array([120, 70, 35], np.float32)
    for _ in range(p.rust_streaks):
        x0, y0 = int(rng.integers(0, n)), int(rng.integers(0, n // 2))
        length, width = int(rng.integers(n // 8, n // 3)), int(rng.integers(3, 9))
        for dy in range(length):
            y = (y0 + dy) % n
            alpha = 0.65 * (1.0 - dy / length)
            x = (x0 + int(3 * np.sin(dy / 17.0))) % n
            cols = np.arange(x - width, x + width) % n
            image[y, cols, :] = (1 - alpha) * image[y, cols, :] + alpha * rust
        cv2.circle(image, (x0, y0), width + 3, tuple(float(c) * 0.7 for c in rust), -1)
    # scratches: thin light and dark line segments
    for _ in range(p.scratches):
        x0, y0 = rng.integers(0, n, 2)
        angle, length = rng.uniform(0, np.pi), rng.integers(20, 120)
        x1, y1 = int(x0 + length * np.cos(angle)), int(y0 + length * np.sin(angle))
        light = rng.choice([True, False])
        if p.scratch_contrast < 0:  # the rough look: black and white scratches
            tone = 230.0 if light else 70.0
        else:
            tone = float(base.mean() + (p.scratch_contrast if light else -p.scratch_contrast))
        cv2.line(image, (int(x0), int(y0)), (x1, y1), (tone, tone, tone), 1, cv2.LINE_AA)
    return np.clip(image, 0, 255).astype(np.uint8)


def fouling_texture(params: TextureParams | None = None) -> np.ndarray:
    """Biofouling: mottled green-brown growth with dark specks, ``(n, n, 3)`` uint8 RGB."""
    p = params or TextureParams()
    rng = np.random.default_rng(p.seed + 1)
    n = p.size_px // 4
    blotch = _noise(rng, n, octaves=(8, 32, 128), weights=(0.5, 0.3, 0.2))
    green, brown = np.array([70, 95, 45], np.float32), np.array([95, 75, 40], np.float32)
    image = green * blotch[..., None] + brown * (1 - blotch[..., None])
    specks = rng.random((n, n)) < 0.03
    image[specks] *= 0.4
    return np.clip(image, 0, 255).astype(np.uint8)


def floor_texture(params: TextureParams | None = None) -> np.ndarray:
    """The tank floor: darker concrete with grit, ``(n, n, 3)`` uint8 RGB."""
    p = params or TextureParams()
    rng = np.random.default_rng(p.seed + 2)
    n = p.size_px // 2
    shade = _noise(rng, n)
    image = np.array([120, 125, 118], np.float32) * (0.7 + 0.4 * shade[..., None])
    image += rng.normal(0.0, 8.0, (n, n, 1)).astype(np.float32)
    return np.clip(image, 0, 255).astype(np.uint8)
