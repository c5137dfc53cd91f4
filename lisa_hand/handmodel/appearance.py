"""Per-subject skin appearance: albedo as a function of the rest-pose surface point.

The colour of a surface point depends only on where it sits on the rest-pose hand (its rest
position and the surface features of :class:`~lisa_hand.handmodel.sdf.HandFieldOutput`: palmar
side, nails, creases, knuckles), so it moves with the skin when the hand is posed. Colours are
display (sRGB-encoded) reflectances in [0, 1]: the colour an evenly lit, unshaded point shows in an
image.

- Skin tone from a palette running from very light to very dark skin (``skin_tone`` 0 -> 1), with
  a red/yellow undertone shift.
- Lighter, pinker palms (more contrast on darker skin, as on real hands).
- Nails: pinkish-white plates, a paler lunula at the cuticle and a whiter free edge.
- Creases, palm lines and knuckle wrinkles darker; dorsal knuckles slightly darker.
- Mild mottling: low-amplitude smooth noise (wavelengths 5-40 mm) seeded per subject.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

__all__ = ["Appearance", "APPEARANCE_BOUNDS", "sample_appearance", "skin_color", "albedo"]

# Dorsal skin colours (sRGB in [0, 1]) from very light to very dark skin.
_PALETTE = np.array(
    [
        [0.96, 0.82, 0.74],
        [0.92, 0.74, 0.63],
        [0.83, 0.62, 0.48],
        [0.68, 0.47, 0.33],
        [0.49, 0.32, 0.22],
        [0.32, 0.20, 0.14],
    ]
)
_PALM_TARGET = np.array([0.93, 0.73, 0.66])
_NAIL_PINK = np.array([0.93, 0.74, 0.72])
_NAIL_WHITE = np.array([0.96, 0.93, 0.88])


@dataclass(frozen=True)
class Appearance:
    """Skin appearance of one subject (defaults: a medium-light skin tone)."""

    skin_tone: float = 0.3
    """0 = very light to 1 = very dark skin."""
    undertone: float = 0.0
    """-1 = yellow/olive to +1 = red/pink undertone."""
    palm_lightness: float = 0.6
    """How much lighter and pinker the palm is than the back of the hand, 0-1."""
    nail_tint: float = 0.6
    """Pinkness of the nail plates, 0 (pale) to 1 (pink)."""
    crease_darkness: float = 0.5
    """Darkening of creases, palm lines and knuckle wrinkles, 0-1."""
    knuckle_darkness: float = 0.3
    """Darkening of the back of the knuckles, 0-1 (stronger on darker skin)."""
    mottling: float = 0.5
    """Strength of the smooth colour noise, 0-1 (1 = +-6 % brightness)."""
    noise_seed: int = 0
    """Seed of the colour noise pattern."""

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if field.name == "noise_seed":
                if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
                    raise TypeError(f"Appearance.noise_seed must be an int, got {value!r}")
                continue
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TypeError(f"Appearance.{field.name} must be a float, got {value!r}")
            low, high = APPEARANCE_BOUNDS[field.name]
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(
                    f"Appearance.{field.name} = {value!r} is outside the valid range "
                    f"[{low}, {high}]"
                )


APPEARANCE_BOUNDS: dict[str, tuple[float, float]] = {
    "skin_tone": (0.0, 1.0),
    "undertone": (-1.0, 1.0),
    "palm_lightness": (0.0, 1.0),
    "nail_tint": (0.0, 1.0),
    "crease_darkness": (0.0, 1.0),
    "knuckle_darkness": (0.0, 1.0),
    "mottling": (0.0, 1.0),
}


def sample_appearance(generator: torch.Generator) -> Appearance:
    """Draw a random appearance: skin tone uniform over the whole light-to-dark range, the other
    parameters uniform over moderate sub-ranges.

    generator: a seeded ``torch.Generator``.
    """
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
    values = torch.rand(7, generator=generator, dtype=torch.float64).tolist()
    seed = int(torch.randint(0, 2**31 - 1, (), generator=generator))
    return Appearance(
        skin_tone=values[0],
        undertone=-0.6 + 1.2 * values[1],
        palm_lightness=0.4 + 0.5 * values[2],
        nail_tint=0.3 + 0.6 * values[3],
        crease_darkness=0.3 + 0.5 * values[4],
        knuckle_darkness=0.1 + 0.6 * values[5],
        mottling=0.2 + 0.6 * values[6],
        noise_seed=seed,
    )


def skin_color(appearance: Appearance) -> np.ndarray:
    """The base dorsal skin colour [3] (sRGB in [0, 1]) of an appearance."""
    position = appearance.skin_tone * (len(_PALETTE) - 1)
    low = min(int(position), len(_PALETTE) - 2)
    frac = position - low
    color = _PALETTE[low] * (1.0 - frac) + _PALETTE[low + 1] * frac
    tint = appearance.undertone
    return np.clip(
        color * np.array([1.0 + 0.05 * tint, 1.0 - 0.01 * tint, 1.0 - 0.06 * tint]), 0, 1
    )


def _noise_waves(seed: int, count: int, low_wavelength: float, high_wavelength: float):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wavelengths = np.exp(rng.uniform(math.log(low_wavelength), math.log(high_wavelength), count))
    return directions * (2.0 * math.pi / wavelengths)[:, None], rng.uniform(0, 2 * math.pi, count)


def albedo(
    appearance: Appearance,
    rest_points: torch.Tensor,
    palmar: torch.Tensor,
    nail: torch.Tensor,
    nail_along: torch.Tensor,
    crease: torch.Tensor,
    knuckle: torch.Tensor,
) -> torch.Tensor:
    """Albedo of surface points from their rest-pose position and surface features.

    rest_points: [N, 3] rest-pose positions (right-hand frame), metres.
    palmar, nail, nail_along, crease, knuckle: [N] in [0, 1] (see ``HandFieldOutput``).
    -> [N, 3] sRGB in [0, 1].
    """
    dtype, device = rest_points.dtype, rest_points.device

    def t(array) -> torch.Tensor:
        return torch.as_tensor(np.asarray(array), dtype=dtype, device=device)

    tone = appearance.skin_tone
    base = t(skin_color(appearance))
    palm_amount = appearance.palm_lightness * (0.25 + 0.55 * tone)
    palm_color = base + (t(_PALM_TARGET) * (1.0 - 0.35 * tone) - base) * palm_amount
    palm_color = torch.maximum(palm_color, base)
    color = base + (palm_color - base) * palmar[:, None]

    # Mottling: brightness and redness noise from low-frequency waves at the rest position.
    freqs, phases = _noise_waves(appearance.noise_seed, 12, 0.005, 0.04)
    waves = torch.sin(rest_points @ t(freqs).T + t(phases))  # [N, 12]
    brightness = 1.0 + 0.06 * appearance.mottling * waves[:, :8].mean(1) * math.sqrt(8.0) / 2.0
    redness = 0.03 * appearance.mottling * waves[:, 8:].mean(1) * 2.0
    color = color * brightness[:, None]
    color = color * (1.0 + redness[:, None] * t([1.0, -0.4, -0.6]))

    # Knuckles: darker (and a little redder on light skin) on the back of the joints.
    dark = appearance.knuckle_darkness * (0.08 + 0.22 * tone) * knuckle
    color = color * (1.0 - dark[:, None] * t([0.8, 1.0, 1.05]))
    # Creases: darker lines.
    color = color * (1.0 - appearance.crease_darkness * 0.3 * crease[:, None])

    # Nails: pinkish plate over the local skin, pale lunula near the cuticle, white free edge.
    nail_base = base + (t(_NAIL_PINK) - base) * (0.7 + 0.25 * appearance.nail_tint)
    nail_base = nail_base * 1.04
    nail_base = nail_base * (1.0 + 0.05 * (appearance.nail_tint - 0.5) * t([0.5, -0.6, -0.4]))
    lunula = torch.clamp(1.0 - nail_along / 0.2, 0.0, 1.0) * 0.35
    free_edge = torch.clamp((nail_along - 0.82) / 0.12, 0.0, 1.0)
    nail_color = (
        nail_base + (t(_NAIL_WHITE) - nail_base) * torch.maximum(lunula, free_edge)[:, None]
    )
    color = color + (nail_color - color) * nail[:, None]
    return color.clamp(0.0, 1.0)
