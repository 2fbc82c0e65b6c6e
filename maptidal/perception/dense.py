"""Dense stereo depth: a surface point wherever the stereo pair matches, not only at keypoints.

The front end's landmarks are its tracked keypoints, and a bare wall gives few: in the default mission
(seed 0) some 30 per m^2 about the walls left uninspected against some 200 about those inspected. A
robot that knows its walls only from them takes much of a bare wall for open water. The OAK-D, the
stereo camera the paper's robots carry, computes disparity and depth for every pixel on the camera
itself, in hardware (Luxonis, "Stereo Depth", docs.luxonis.com/software-v3/support/faq/stereo-depth),
so a robot has that depth as well as its keypoints. This module computes such a depth map with OpenCV's
semi-global block matching (Hirschmuller 2008, "Stereo processing by semiglobal matching and mutual
information") and returns one point per ``stride_px`` cell of the left image, in the world, from the
keyframe's camera pose.

A match needs texture. Semi-global matching gives a disparity wherever its smoothness terms carry one,
and in a patch with nothing in it but the camera's noise it fits that noise: seen from below, the water
surface is a flat veil of colour, and there the matcher put points in open water 0.5 to 1.3 m from the
camera (the deeper tank variant's wall tops, where such points kept views out). OpenCV's block matcher
has a texture threshold for this; semi-global matching has none, so this module adds one, set from the
camera's noise rather than fitted to images: a pixel whose ``block_size`` block in the left image varies
no more than noise alone would at ``texture_confidence`` gets no match (:func:`texture_threshold`).

Pure numpy, scipy and OpenCV: it runs on a real robot's rectified pairs as well.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.stats import chi2

from maptidal.perception.stereo import gray_image

__all__ = [
    "DenseDepthParams",
    "dense_points",
    "disparity_map",
    "gray_noise_sigma",
    "texture_threshold",
    "textured_pixels",
]

# the weights of OpenCV's RGB to grey conversion (cv2.COLOR_RGB2GRAY: ITU-R BT.601 luma, Y = 0.299 R +
# 0.587 G + 0.114 B; OpenCV's "Color conversions" reference)
GRAY_WEIGHTS = (0.299, 0.587, 0.114)


@dataclass(frozen=True)
class DenseDepthParams:
    """Semi-global matching and sampling settings. The defaults are OpenCV's documented starting points
    for SGBM (P1 = 8 x channels x block^2, P2 = 32 x channels x block^2; uniqueness 5 to 15; speckle
    window 50 to 200, range 1 or 2: the StereoSGBM reference) and the mission's camera."""

    # a multiple of 16: 32 px at the mission's 320 px images (f = 196 px, 7.5 cm baseline) reaches down
    # to f B / 32 = 0.46 m, closer than the 0.55 m a robot keeps from every surface
    num_disparities: int = 32
    block_size: int = 5
    uniqueness_ratio: int = 10
    speckle_window: int = 50
    speckle_range: int = 2
    # the left-right check: a pixel whose match back from the right image lands over 1 px away is dropped
    max_lr_difference_px: int = 1
    # one point per 8 x 8 px cell: 6 cm apart on a wall 1.5 m away, finer than the map's 10 cm cells
    stride_px: int = 8
    # the map's useful range (MapAwareParams.look_range_m): beyond 3 m a single observation's depth error
    # exceeds 15 cm (z^2 x 0.25 px / (196 px x 0.075 m))
    max_depth_m: float = 3.0
    # the std of the camera's additive noise in each 8-bit colour channel (the simulator's [water]
    # noise_sigma; a real camera's from frames of a flat, still target); 0 leaves only rounding noise
    pixel_noise_sigma: float = 0.0
    # how sure the texture test must be that a block holds more than noise: a block of noise alone
    # passes with probability 1 - texture_confidence; 0 turns the test off
    texture_confidence: float = 0.99

    def __post_init__(self) -> None:
        if not (
            isinstance(self.num_disparities, int)
            and self.num_disparities > 0
            and self.num_disparities % 16 == 0
        ):
            raise ValueError(
                f"num_disparities must be a positive multiple of 16, got {self.num_disparities!r}"
            )
        if not (isinstance(self.block_size, int) and self.block_size >= 1 and self.block_size % 2 == 1):
            raise ValueError(f"block_size must be an odd positive integer, got {self.block_size!r}")
        for name in ("uniqueness_ratio", "speckle_window", "speckle_range", "max_lr_difference_px"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 0):
                raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
        if not (isinstance(self.stride_px, int) and self.stride_px >= 1):
            raise ValueError(f"stride_px must be a positive integer, got {self.stride_px!r}")
        if not (math.isfinite(self.max_depth_m) and self.max_depth_m > 0):
            raise ValueError(f"max_depth_m must be a positive number, got {self.max_depth_m!r}")
        if not (math.isfinite(self.pixel_noise_sigma) and self.pixel_noise_sigma >= 0):
            raise ValueError(f"pixel_noise_sigma must be a number >= 0, got {self.pixel_noise_sigma!r}")
        if not (0.0 <= self.texture_confidence < 1.0):
            raise ValueError(f"texture_confidence must be in [0, 1), got {self.texture_confidence!r}")


def gray_noise_sigma(pixel_noise_sigma: float, channels: int = 3) -> float:
    """The std (grey levels) of the noise in the 8-bit grey image of an 8-bit image whose channels carry
    independent noise of std ``pixel_noise_sigma``. Each rounding to 8 bits adds an error uniform over
    one level, of variance 1/12 (Widrow and Kollar, "Quantization Noise", 2008). For an RGB image
    (``channels`` 3) that is the weighted sum's variance, (sigma^2 + 1/12) sum(w^2), plus the grey
    value's own rounding; for a grey image (``channels`` 1), sigma^2 + 1/12."""
    if channels == 1:
        return math.sqrt(pixel_noise_sigma**2 + 1.0 / 12.0)
    squares = sum(w * w for w in GRAY_WEIGHTS)
    return math.sqrt((pixel_noise_sigma**2 + 1.0 / 12.0) * squares + 1.0 / 12.0)


def texture_threshold(noise_sigma: float, block_size: int, confidence: float) -> float:
    """The sample standard deviation (grey levels) that a ``block_size`` x ``block_size`` block of a flat
    patch under Gaussian noise of std ``noise_sigma`` stays at or below with probability ``confidence``:
    (n - 1) s^2 / sigma^2 follows chi-square with n - 1 degrees of freedom (n pixels), so the bound is
    sigma sqrt(chi2_confidence(n - 1) / (n - 1)). 0 for ``confidence`` 0."""
    if confidence <= 0.0:
        return 0.0
    dof = block_size * block_size - 1
    return noise_sigma * math.sqrt(chi2.ppf(confidence, dof) / dof)


def textured_pixels(gray: np.ndarray, block_size: int, threshold: float) -> np.ndarray:
    """Where the ``block_size`` block about each pixel of ``gray`` has a sample standard deviation above
    ``threshold`` (bool, the image's shape; blocks at the border are reflected in it, as the matcher's)."""
    gray = np.asarray(gray)
    # an 8-bit image's block sums are whole numbers, exact in float32, and n S2 - S1^2 is exact in a
    # double; any other image is summed in doubles
    depth = cv2.CV_32F if gray.dtype == np.uint8 else cv2.CV_64F
    if depth == cv2.CV_64F:
        gray = gray.astype(np.float64)
    size, border = (block_size, block_size), cv2.BORDER_REFLECT_101
    sums = cv2.boxFilter(gray, depth, size, normalize=False, borderType=border).astype(np.float64)
    squares = cv2.sqrBoxFilter(gray, depth, size, normalize=False, borderType=border).astype(np.float64)
    n = block_size * block_size
    # n times the sum of squared deviations from the block's mean, n S2 - S1^2, against n (n - 1) s^2
    spread = n * squares - sums * sums
    return spread > n * (n - 1) * threshold * threshold


def disparity_map(left: np.ndarray, right: np.ndarray, params: DenseDepthParams) -> np.ndarray:
    """The left image's disparity (px, float32) by semi-global matching; NaN where there is no match,
    or where the left image's block has no more texture than the camera's noise (module docstring)."""
    left_gray, right_gray = gray_image(left, "left"), gray_image(right, "right")
    if left_gray.shape != right_gray.shape:
        raise ValueError(f"the stereo pair's sizes differ: {left_gray.shape} and {right_gray.shape}")
    block = params.block_size
    matcher = cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=params.num_disparities,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        disp12MaxDiff=params.max_lr_difference_px,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window,
        speckleRange=params.speckle_range,
        # the three-way variant: the same depth on the tank's walls (tested) in under half the time
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    raw = matcher.compute(left_gray, right_gray).astype(np.float32) / 16.0  # fixed point, 4 fraction bits
    matched = raw > 0.0
    if params.texture_confidence > 0.0:
        channels = 3 if np.asarray(left).ndim == 3 else 1
        noise = gray_noise_sigma(params.pixel_noise_sigma, channels)
        threshold = texture_threshold(noise, block, params.texture_confidence)
        matched &= textured_pixels(left_gray, block, threshold)
    return np.where(matched, raw, np.nan).astype(np.float32)


def dense_points(
    left: np.ndarray,
    right: np.ndarray,
    intrinsics,
    position: np.ndarray,
    rotation: np.ndarray,
    params: DenseDepthParams | None = None,
) -> np.ndarray:
    """World points ``(N, 3)`` of the rectified pair's dense depth, one per ``stride_px`` cell of the left
    image (its centre pixel) where the pair matched, within ``max_depth_m``. ``intrinsics`` has ``fx``,
    ``fy``, ``cx``, ``cy`` and ``baseline_m``; ``position`` and ``rotation`` are the left camera's pose
    in the world (``rotation``'s columns: right, down, forward). A pose with NaNs gives no points."""
    params = params or DenseDepthParams()
    position = np.asarray(position, float).reshape(3)
    rotation = np.asarray(rotation, float).reshape(3, 3)
    if not (np.isfinite(position).all() and np.isfinite(rotation).all()):
        return np.zeros((0, 3))
    disparity = disparity_map(left, right, params)
    half = params.stride_px // 2
    rows = np.arange(half, disparity.shape[0], params.stride_px)
    columns = np.arange(half, disparity.shape[1], params.stride_px)
    v, u = np.meshgrid(rows, columns, indexing="ij")
    d = disparity[v, u].astype(float)
    k = intrinsics
    with np.errstate(invalid="ignore", divide="ignore"):
        z = k.fx * k.baseline_m / d
    keep = np.isfinite(z) & (z > 0) & (z <= params.max_depth_m)
    u, v, z = u[keep].astype(float), v[keep].astype(float), z[keep]
    camera = np.column_stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z])
    return position + camera @ rotation.T
