"""The one stereo camera of maptidal: the OAK-D's mono pair, as a pinhole from its datasheet.

The paper's robots carry a Luxonis OAK-D. Its stereo pair, by Luxonis' OAK-D spec sheet
(docs.luxonis.com, "OAK-D", camera specs, stereo pair):

- sensor OV9282 (global shutter), 1280 x 800 native, pixel 3.0 x 3.0 um;
- effective focal length 2.35 mm, DFOV / HFOV / VFOV 89 / 80 / 55 deg, distortion < 1 %;
- baseline 7.5 cm.

So the focal length is 2.35 mm / 3 um = 783 px at 1280 x 800 and 392 px in the 640 x 400
binned mode, with square pixels and the principal point at the image centre. A pinhole of
that focal length spans 78.5 x 54.1 deg at 640 x 400; the spec sheet's 80 x 55 deg includes
the lens's small distortion, which we do not model.

Rendering (``maptidal.envs``), the synthetic keyframes, the frustum of discovery and coverage, and
``Simulation.intrinsics()`` all take their numbers from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Luxonis OAK-D spec sheet, stereo pair (OV9282)
OAKD_FOCAL_LENGTH_MM = 2.35
OAKD_PIXEL_SIZE_UM = 3.0
OAKD_NATIVE_WIDTH_PX = 1280
OAKD_NATIVE_HEIGHT_PX = 800
OAKD_BASELINE_M = 0.075


@dataclass(frozen=True)
class StereoCameraParams:
    """A rectified stereo pair as a pinhole: image size, optics, baseline and the stereo noise model.

    The focal length in pixels follows from the optics: ``f = focal_length / (pixel_size x
    binning)``, with binning the native width over ``width`` (and height over ``height``), so
    every image size keeps the sensor's field of view. Defaults are the OAK-D's 640 x 400 mode.

    The disparity noise of 0.25 px is our assumption (sub-pixel matching; about 0.8 % depth
    error at 1 m). ``min_range_m``, ``max_range_m``, ``max_keypoints`` and
    ``occlusion_tolerance_m`` are modelling choices of the synthetic front end.
    """

    width: int = 640
    height: int = 400
    focal_length_mm: float = OAKD_FOCAL_LENGTH_MM
    pixel_size_um: float = OAKD_PIXEL_SIZE_UM
    native_width_px: int = OAKD_NATIVE_WIDTH_PX
    native_height_px: int = OAKD_NATIVE_HEIGHT_PX
    baseline_m: float = OAKD_BASELINE_M
    min_range_m: float = 0.3
    max_range_m: float = 3.5
    disparity_sigma_px: float = 0.25
    max_keypoints: int = 300
    occlusion_tolerance_m: float = 0.03

    def __post_init__(self) -> None:
        for name in ("width", "height", "native_width_px", "native_height_px", "max_keypoints"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value > 0):
                raise ValueError(f"camera {name} must be a positive whole number, got {value!r}")
        for name in ("focal_length_mm", "pixel_size_um", "baseline_m", "max_range_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"camera {name} must be a positive finite number, got {value!r}")
        if not (math.isfinite(self.min_range_m) and 0 <= self.min_range_m < self.max_range_m):
            raise ValueError(f"camera min_range_m must be in [0, max_range_m), got {self.min_range_m!r}")

    @property
    def fx(self) -> float:
        """Horizontal focal length in pixels: focal length over the (binned) pixel width."""
        binning = self.native_width_px / self.width
        return self.focal_length_mm * 1e3 / (self.pixel_size_um * binning)

    @property
    def fy(self) -> float:
        """Vertical focal length in pixels (equal to fx when the image keeps the sensor's aspect)."""
        binning = self.native_height_px / self.height
        return self.focal_length_mm * 1e3 / (self.pixel_size_um * binning)

    @property
    def cx(self) -> float:
        """Principal point, x (px): the image centre."""
        return self.width / 2.0

    @property
    def cy(self) -> float:
        """Principal point, y (px): the image centre."""
        return self.height / 2.0

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the pinhole (deg)."""
        return math.degrees(2.0 * math.atan(self.width / 2.0 / self.fx))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view of the pinhole (deg)."""
        return math.degrees(2.0 * math.atan(self.height / 2.0 / self.fy))

    def matrix(self) -> np.ndarray:
        """The 3 x 3 intrinsic matrix K (pixels; x right, y down)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def depth_sigma(self, depth: np.ndarray) -> np.ndarray:
        """Stereo depth noise (m) at depth ``depth``: z^2 sigma_d / (f_x b)."""
        return np.asarray(depth) ** 2 * self.disparity_sigma_px / (self.fx * self.baseline_m)


OAKD = StereoCameraParams()
OAKD_HFOV_DEG = OAKD.hfov_deg  # 78.5 deg at 640 x 400
OAKD_VFOV_DEG = OAKD.vfov_deg  # 54.1 deg
