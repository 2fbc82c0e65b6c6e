"""Underwater image formation: attenuation and backscatter from the depth buffer.

Each rendered RGB frame ``J`` becomes, per colour channel ``c`` and pixel range ``d``
(metres along the ray, from the depth buffer)::

    I_c = J_c exp(-beta_c d) + B_inf,c (1 - exp(-beta_c d))

(the standard model, e.g. Akkaynak & Treibitz, CVPR 2018, with one coefficient for
the direct and the backscattered signal). A single ``turbidity`` knob in [0, 1]
picks the water: it interpolates between Jerlov-like water types, from clear
oceanic water (type I) to turbid coastal water (type 9C).

Coefficients (1/m, for red ~600 nm, green ~525 nm, blue ~475 nm) are rounded,
approximate diffuse attenuation values of the Jerlov types as tabulated by
Solonenko & Mobley (Appl. Opt. 54(17), 2015); the veiling-light colours B_inf are
our choice (blue in clear water, green in coastal water). Treat them as plausible
defaults, not measurements of any one tank.

The same :class:`WaterParams` goes to both cameras of a pair, so they see the same
water; sensor noise (optional) is drawn independently per camera, as on real sensors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# turbidity knob position, name, beta (R, G, B) 1/m, B_inf (R, G, B) in [0, 1]
WATER_TYPES: tuple[tuple[float, str, tuple[float, float, float], tuple[float, float, float]], ...] = (
    (0.0, "Jerlov I", (0.25, 0.05, 0.03), (0.02, 0.18, 0.32)),
    (0.25, "Jerlov III", (0.30, 0.10, 0.12), (0.03, 0.22, 0.30)),
    (0.5, "Jerlov 1C", (0.40, 0.17, 0.25), (0.05, 0.26, 0.26)),
    (0.75, "Jerlov 3C", (0.55, 0.30, 0.50), (0.08, 0.30, 0.22)),
    (1.0, "Jerlov 9C", (1.00, 0.80, 1.40), (0.12, 0.30, 0.16)),
)
_LUT_STEP_M = 0.005
_LUT_MAX_M = 30.0


@dataclass(frozen=True)
class WaterParams:
    """The water the cameras look through.

    ``turbidity`` in [0, 1] selects the Jerlov-like type (see module docstring);
    ``noise_sigma`` is the std of additive Gaussian sensor noise in 8-bit levels;
    ``vignetting`` the relative darkening at the image corners (0 = none).
    """

    turbidity: float = 0.3
    noise_sigma: float = 0.0
    vignetting: float = 0.0
    enabled: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.turbidity <= 1.0:
            raise ValueError(f"turbidity must be in [0, 1], got {self.turbidity}")
        if self.noise_sigma < 0 or not 0.0 <= self.vignetting < 1.0:
            raise ValueError("noise_sigma must be >= 0 and vignetting in [0, 1)")

    def coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """Attenuation ``beta`` (1/m) and veiling light ``B_inf`` (0-1), each ``(3,)`` RGB."""
        knots = np.array([w[0] for w in WATER_TYPES])
        betas = np.array([w[2] for w in WATER_TYPES])
        veils = np.array([w[3] for w in WATER_TYPES])
        beta = np.array([np.interp(self.turbidity, knots, betas[:, c]) for c in range(3)])
        veil = np.array([np.interp(self.turbidity, knots, veils[:, c]) for c in range(3)])
        return beta, veil


class WaterModel:
    """Applies :class:`WaterParams` to frames; precomputes a transmission lookup table."""

    def __init__(self, params: WaterParams | None = None) -> None:
        self.params = params or WaterParams()
        beta, veil = self.params.coefficients()
        ranges = np.arange(0.0, _LUT_MAX_M + _LUT_STEP_M, _LUT_STEP_M, dtype=np.float32)
        self._transmission = np.exp(-np.outer(ranges, beta)).astype(np.float32)  # (K, 3)
        self._veil = (255.0 * veil).astype(np.float32)
        self._vignette: dict[tuple[int, int], np.ndarray] = {}

    def transmission(self, range_m: np.ndarray) -> np.ndarray:
        """exp(-beta d) per channel, ``(..., 3)``, for ranges in metres (looked up at 5 mm steps)."""
        index = np.clip(np.rint(np.asarray(range_m) / _LUT_STEP_M), 0, len(self._transmission) - 1)
        return self._transmission[index.astype(np.int32)]

    def _vignette_mask(self, height: int, width: int) -> np.ndarray:
        key = (height, width)
        if key not in self._vignette:
            y, x = np.mgrid[0:height, 0:width].astype(np.float32)
            r2 = ((x - width / 2) / (width / 2)) ** 2 + ((y - height / 2) / (height / 2)) ** 2
            self._vignette[key] = (1.0 - self.params.vignetting * r2 / 2.0)[..., None].astype(np.float32)
        return self._vignette[key]

    def apply(
        self, rgb: np.ndarray, range_m: np.ndarray, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """The underwater image (uint8 RGB) of a clear-water render and its per-pixel range."""
        if not self.params.enabled:
            return rgb
        t = self.transmission(range_m)
        image = rgb.astype(np.float32)
        image -= self._veil  # I = B + (J - B) t, in place to keep it fast at 640x400
        image *= t
        image += self._veil
        if self.params.vignetting > 0:
            image *= self._vignette_mask(*rgb.shape[:2])
        if self.params.noise_sigma > 0:
            rng = rng or np.random.default_rng()
            image += rng.normal(0.0, self.params.noise_sigma, image.shape).astype(np.float32)
        return np.clip(image, 0, 255).astype(np.uint8)


def depth_to_range(depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Range along each pixel's ray (m) from planar depth (distance along the optical axis)."""
    height, width = depth_m.shape
    u = (np.arange(width, dtype=np.float32) + 0.5 - cx) / fx
    v = (np.arange(height, dtype=np.float32) + 0.5 - cy) / fy
    scale = np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)
    return depth_m * scale
