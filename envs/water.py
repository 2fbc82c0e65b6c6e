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

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

# turbidity knob position, name, beta (R, G, B) 1/m, B_inf (R, G, B) in [0, 1]
WATER_TYPES: tuple[tuple[float, str, tuple[float, float, float], tuple[float, float, float]], ...] = (
    (0.0, "Jerlov I", (0.25, 0.05, 0.03), (0.02, 0.18, 0.32)),
    (0.25, "Jerlov III", (0.30, 0.10, 0.12), (0.03, 0.22, 0.30)),
    (0.5, "Jerlov 1C", (0.40, 0.17, 0.25), (0.05, 0.26, 0.26)),
    (0.75, "Jerlov 3C", (0.55, 0.30, 0.50), (0.08, 0.30, 0.22)),
    (1.0, "Jerlov 9C", (1.00, 0.80, 1.40), (0.12, 0.30, 0.16)),
)


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


def visibility_limit_m(beta: np.ndarray) -> float:
    """Range (m) beyond which every channel is attenuated below exp(-60): nothing is visible there,
    and clamping to it keeps float32 arithmetic out of slow denormals."""
    return 60.0 / max(float(np.min(beta)), 1e-6)


_NOISE_BANK_SIZE = 1 << 22  # standard normal draws shared by every camera (16 MB, made once)
_bank: list[np.ndarray] = []


def _noise_bank() -> np.ndarray:
    """A fixed bank of standard normal draws. Each frame reads a window at a random offset (drawn from
    the simulation's seeded generator), which costs a slice instead of 768k fresh draws per frame.
    Windows of two frames may overlap, so one frame's noise can reappear in another shifted by the
    offsets' difference, but at the same pixels only if the offsets coincide (1 in 3.4 million).
    The GL water pass (:mod:`maptidal.envs.gl_water`) hashes each pixel instead and has no such overlap."""
    if not _bank:
        _bank.append(np.random.default_rng(20260).standard_normal(_NOISE_BANK_SIZE, dtype=np.float32))
    return _bank[0]


class WaterModel:
    """Applies :class:`WaterParams` to frames.

    The formula is evaluated exactly, per colour plane with OpenCV, on two threads (about 1.1 ms for a
    640 x 400 frame on a 2-core CPU; 2 ms on one thread, 23 ms for the same arithmetic in numpy)."""

    def __init__(self, params: WaterParams | None = None) -> None:
        self.params = params or WaterParams()
        beta, veil = self.params.coefficients()
        self._beta = [float(b) for b in beta]
        self._max_range = visibility_limit_m(beta)
        self._veil = [float(255.0 * v) for v in veil]
        self._vignette: dict[tuple[int, int], np.ndarray] = {}

    def _vignette_mask(self, height: int, width: int) -> np.ndarray:
        key = (height, width)
        if key not in self._vignette:
            y, x = np.mgrid[0:height, 0:width].astype(np.float32)
            r2 = ((x - width / 2) / (width / 2)) ** 2 + ((y - height / 2) / (height / 2)) ** 2
            self._vignette[key] = (1.0 - self.params.vignetting * r2 / 2.0).astype(np.float32)
        return self._vignette[key]

    def apply(
        self, rgb: np.ndarray, range_m: np.ndarray, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """The underwater image (uint8 RGB) of a clear-water render and its per-pixel range (m).

        The upper and lower halves of the frame are computed on two threads (OpenCV releases the GIL);
        the result does not depend on the split."""
        if not self.params.enabled:
            return rgb
        rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
        distance = cv2.min(np.asarray(range_m, dtype=np.float32), self._max_range)
        vignette = self._vignette_mask(*distance.shape) if self.params.vignetting > 0 else None
        noise = None
        if self.params.noise_sigma > 0:
            rng = rng or np.random.default_rng()
            bank = _noise_bank()
            start = int(rng.integers(0, len(bank) - 3 * distance.size))
            noise = bank[start : start + 3 * distance.size].reshape(3, *distance.shape)
        out = np.empty_like(rgb)
        height = distance.shape[0]
        if height < _SPLIT_MIN_ROWS:
            self._apply_rows(rgb, distance, vignette, noise, out, slice(0, height))
            return out
        middle = height // 2
        # its own thread: the simulation's water thread may be the caller, waiting on this half
        half_thread = worker_thread("maptidal-water-half")
        upper = half_thread.submit(self._apply_rows, rgb, distance, vignette, noise, out, slice(0, middle))
        self._apply_rows(rgb, distance, vignette, noise, out, slice(middle, height))
        upper.result()
        return out

    def _apply_rows(
        self,
        rgb: np.ndarray,
        distance: np.ndarray,
        vignette: np.ndarray | None,
        noise: np.ndarray | None,
        out: np.ndarray,
        rows: slice,
    ) -> None:
        """Write rows ``rows`` of the underwater image into ``out``."""
        distance = distance[rows]
        transmission = np.empty(distance.shape, np.float32)
        signal = np.empty(distance.shape, np.float32)
        planes = []
        for channel, plane in enumerate(cv2.split(rgb[rows])):
            cv2.multiply(distance, -self._beta[channel], dst=transmission)
            cv2.exp(transmission, dst=transmission)
            # I = B + (J - B) t
            cv2.subtract(plane, self._veil[channel], dst=signal, dtype=cv2.CV_32F)
            cv2.multiply(signal, transmission, dst=signal)
            if vignette is None and noise is None:
                planes.append(cv2.convertScaleAbs(signal, alpha=1.0, beta=self._veil[channel]))
                continue
            cv2.add(signal, self._veil[channel], dst=signal)
            if vignette is not None:
                cv2.multiply(signal, vignette[rows], dst=signal)
            if noise is not None:
                cv2.scaleAdd(noise[channel, rows], self.params.noise_sigma, signal, dst=signal)
                cv2.max(signal, 0.0, dst=signal)  # clip, since convertScaleAbs would mirror negatives
            planes.append(cv2.convertScaleAbs(signal))
        out[rows] = cv2.merge(planes)


_SPLIT_MIN_ROWS = 64  # smaller frames are not worth a second thread


@functools.cache
def worker_thread(name: str) -> ThreadPoolExecutor:
    """The process's single worker thread called ``name``, made on first use. Work that waits on
    another worker must use a different name, or the one thread would wait on itself."""
    return ThreadPoolExecutor(1, thread_name_prefix=name)


def depth_to_range(depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Range along each pixel's ray (m) from planar depth (distance along the optical axis)."""
    height, width = depth_m.shape
    u = (np.arange(width, dtype=np.float32) + 0.5 - cx) / fx
    v = (np.arange(height, dtype=np.float32) + 0.5 - cy) / fy
    scale = np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)
    return depth_m * scale
