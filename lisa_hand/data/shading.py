"""How the ground-truth images are lit and coloured: Lambertian plus ambient shading, random
lights, and a per-camera colour response.

Per pixel (:func:`shade`)::

    rgb = clip(gain * albedo * (ambient + diffuse / L * sum_l max(0, n . l)) + bias, 0, 1)

with ``n`` the unit outward normal, ``l`` the unit direction *towards* light ``l`` (L lights,
:class:`ShadingConfig`, :func:`lights_per_view`) and ``gain``, ``bias`` a per-camera,
per-channel colour response (:class:`GainBiasConfig`, :class:`GainBias`; the "color calibration"
of LISA Section 4.2). Randomness comes only from the numpy Generator given
(:func:`as_generator`). Arrays are numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry.cameras import Camera
from ..utils.arrays import as_numpy

__all__ = [
    "ShadingConfig",
    "GainBiasConfig",
    "GainBias",
    "as_generator",
    "sample_cone",
    "resolve_gain_bias",
    "lights_per_view",
    "shade",
]


@dataclass(frozen=True)
class ShadingConfig:
    """Lambertian plus ambient shading of the ground-truth images."""

    ambient: float = 0.35
    """Ambient intensity (unitless; a surface facing away from every light gets albedo * this)."""
    diffuse: float = 0.65
    """Total diffuse intensity, shared equally by the lights (ambient + diffuse = 1 keeps a
    surface facing the light at its albedo)."""
    light_directions: tuple[tuple[float, float, float], ...] = ((0.0, -0.5, -1.0),)
    """Directions *towards* the lights (normalised here), in ``light_frame``. The default, in the
    camera frame (x right, y down, z forward), is a light at the camera, slightly above it."""
    light_frame: str = "camera"
    """"camera": each view lit from the same place relative to its camera (a flash);
    "world": one set of lights for the whole scene."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """RGB in [0, 1] where no surface is hit; black, as masked InterHand2.6M images."""
    random_light: bool = False
    """Jitter each light direction uniformly in a cone of ``light_jitter_deg``: per view in the
    camera frame, once per :func:`render_views` call (one scene) in the world frame."""
    light_jitter_deg: float = 30.0
    """Half-angle of the random light cone, degrees."""

    def __post_init__(self) -> None:
        for name in ("ambient", "diffuse"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        lights = np.asarray(self.light_directions, dtype=np.float64)
        if lights.ndim != 2 or lights.shape[0] < 1 or lights.shape[1] != 3:
            raise ValueError(f"light_directions must be a non-empty list of 3-vectors, got shape "
                             f"{list(lights.shape)}")
        if not (np.isfinite(lights).all() and (np.linalg.norm(lights, axis=1) > 0).all()):
            raise ValueError(f"light_directions must be finite, non-zero vectors, got "
                             f"{lights.tolist()}")
        if self.light_frame not in ("camera", "world"):
            raise ValueError(f"light_frame must be 'camera' or 'world', got {self.light_frame!r}")
        background = np.asarray(self.background, dtype=np.float64)
        if background.shape != (3,) or not ((background >= 0) & (background <= 1)).all():
            raise ValueError(f"background must be 3 values in [0, 1], got {self.background!r}")
        if not 0.0 <= self.light_jitter_deg <= 180.0:
            raise ValueError(f"light_jitter_deg must be in [0, 180], got {self.light_jitter_deg}")

    def unit_lights(self) -> np.ndarray:
        """[L, 3] unit directions towards the lights, in ``light_frame``."""
        lights = np.asarray(self.light_directions, dtype=np.float64)
        return lights / np.linalg.norm(lights, axis=1, keepdims=True)


@dataclass(frozen=True)
class GainBiasConfig:
    """Random per-camera, per-channel colour response ``gain * rgb + bias`` (uncalibrated)."""

    gain_range: tuple[float, float] = (0.85, 1.15)
    """Each camera's gain per channel is uniform in this range (unitless)."""
    bias_range: tuple[float, float] = (-0.05, 0.05)
    """Each camera's bias per channel is uniform in this range (colour units, [0, 1] scale)."""

    def __post_init__(self) -> None:
        for name in ("gain_range", "bias_range"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(f"{name} must be finite (low, high) with low <= high, got "
                                 f"{getattr(self, name)!r}")

    def sample(self, num_cameras: int, generator: np.random.Generator) -> GainBias:
        """Draw gains then biases, [num_cameras, 3] each."""
        gain = generator.uniform(*self.gain_range, size=(num_cameras, 3))
        bias = generator.uniform(*self.bias_range, size=(num_cameras, 3))
        return GainBias(gain=gain, bias=bias)


@dataclass(frozen=True, eq=False)
class GainBias:
    """Explicit per-camera colour response.

    gain: [C, 3] (or [3], shared) unitless; bias: [C, 3] (or [3]) colour units.
    """

    gain: np.ndarray
    bias: np.ndarray

    def __post_init__(self) -> None:
        for name in ("gain", "bias"):
            value = np.asarray(as_numpy(getattr(self, name), name), dtype=np.float32)
            if value.ndim not in (1, 2) or value.shape[-1] != 3 or not np.isfinite(value).all():
                raise ValueError(f"{name} must be finite with shape [C, 3] or [3], got "
                                 f"{list(value.shape)}")
            object.__setattr__(self, name, value)

    def for_camera(self, index: int, num_cameras: int) -> tuple[np.ndarray, np.ndarray]:
        """(gain [3], bias [3]) of camera ``index``."""
        out = []
        for name in ("gain", "bias"):
            value = getattr(self, name)
            if value.ndim == 2:
                if value.shape[0] != num_cameras:
                    raise ValueError(f"{name} has {value.shape[0]} rows for {num_cameras} "
                                     f"cameras (shape {list(value.shape)})")
                value = value[index]
            out.append(value)
        return out[0], out[1]


def as_generator(generator, needed: bool, what: str) -> np.random.Generator | None:
    if generator is None:
        if needed:
            raise ValueError(f"generator must be a numpy Generator or an int seed when {what}")
        return None
    if isinstance(generator, np.random.Generator):
        return generator
    if isinstance(generator, (int, np.integer)) and not isinstance(generator, bool):
        return np.random.default_rng(int(generator))
    raise TypeError(f"generator must be a numpy Generator, an int seed or None, got "
                    f"{type(generator).__name__}")


def sample_cone(axis: np.ndarray, half_angle_deg: float,
                 generator: np.random.Generator) -> np.ndarray:
    """A unit vector uniform on the spherical cap of ``half_angle_deg`` around unit ``axis``."""
    cos_max = math.cos(math.radians(half_angle_deg))
    cos_theta = generator.uniform(cos_max, 1.0)
    phi = generator.uniform(0.0, 2.0 * math.pi)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(axis, helper)
    first /= np.linalg.norm(first)
    second = np.cross(axis, first)
    sin_theta = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    return (cos_theta * axis + sin_theta * (math.cos(phi) * first + math.sin(phi) * second))


def resolve_gain_bias(gain_bias, num_cameras: int, generator) -> GainBias | None:
    if gain_bias is None:
        return None
    if isinstance(gain_bias, GainBiasConfig):
        return gain_bias.sample(num_cameras, generator)
    if isinstance(gain_bias, GainBias):
        gain_bias.for_camera(0, num_cameras)  # validates the row count
        return gain_bias
    raise TypeError(f"gain_bias must be None, a GainBiasConfig or a GainBias, got "
                    f"{type(gain_bias).__name__}")


def lights_per_view(cameras: list[Camera], shading: ShadingConfig,
                     generator: np.random.Generator | None) -> list[np.ndarray]:
    """World-frame unit light directions [L, 3] for each camera (sampling the random lights)."""
    lights = shading.unit_lights()

    def jitter(directions: np.ndarray) -> np.ndarray:
        if not shading.random_light:
            return directions
        return np.stack([sample_cone(direction, shading.light_jitter_deg, generator)
                         for direction in directions])

    if shading.light_frame == "world":
        world = jitter(lights).astype(np.float32)
        return [world.copy() for _ in cameras]
    out = []
    for camera in cameras:
        rotation = camera.R.detach().cpu().double().numpy()
        out.append((jitter(lights) @ rotation).astype(np.float32))  # R^T l for each row l
    return out


def shade(normals: np.ndarray, albedo: np.ndarray, lights: np.ndarray, gain: np.ndarray,
          bias: np.ndarray, shading: ShadingConfig) -> np.ndarray:
    """The shaded colour of surface points (see the module docstring).

    normals: [N, 3] unit world normals. albedo: [N, 3] in [0, 1]. lights: [L, 3] unit world
    directions towards the lights. gain, bias: [3]. -> [N, 3] in [0, 1].
    """
    lambert = np.clip(normals @ lights.T, 0.0, None).mean(axis=1)  # [N]
    intensity = shading.ambient + shading.diffuse * lambert
    return np.clip(gain * (albedo * intensity[:, None]) + bias, 0.0, 1.0)
