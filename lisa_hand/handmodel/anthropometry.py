"""Shape variation of hand model v2: drawn from published adult hand anthropometry.

Hand model v1 draws each :class:`~lisa_hand.handmodel.shape.HandShape` parameter from its own
clipped normal (:func:`lisa_hand.handmodel.shape.sample_shape`). Version 2 draws the measured
dimensions of a hand jointly, from a **mixed adult population**: a 50/50 mixture of a female
and a male multivariate normal over

====================  =========================================================  =======  ======
measurement           definition                                                  female   male
====================  =========================================================  =======  ======
``hand_length``       wrist crease to the tip of the middle finger, mm            175 (9)  190 (10)
``hand_breadth``      across the metacarpal heads (index to little finger), mm   75 (4)   85 (5)
``palm_thickness``    dorsal to palmar at the metacarpal heads, mm               25 (2)   28.5 (2)
``digit_ratio``       2D:4D, index over ring finger length                       0.969    0.957
                                                                                  (0.033)  (0.032)
``index_ratio``       index over middle finger length                            0.93     0.925
``pinky_ratio``       little over middle finger length                           0.78     0.78
====================  =========================================================  =======  ======

(means, standard deviations in brackets; finger-ratio SDs 0.022 and 0.028). Sources, and how
firm each number is:

* hand breadth: British adults aged 19-65 (Pheasant & Haslegrave, *Bodyspace*, 3rd ed. 2006,
  dimension 29), 5th/50th/95th percentiles 70/75/85 mm and SD 4 for women, 80/85/95 mm and SD
  5 for men, as tabulated by the City University of Hong Kong's online anthropometry course
  (ch. 2-29): taken as they are;
* 2D:4D: Brañas-Garza et al., 1011 Caucasian adults (Granada), right hands: population means
  0.954-0.961 (men) and 0.966-0.972 (women, 80 % of them between 0.926 and 1.011, hence an SD
  of about 0.033): taken as they are;
* hand length (wrist crease to middle fingertip), palm thickness at the metacarpal heads, the
  within-sex correlations and the finger-length ratios are **rounded values of the order the
  surveys report, not transcribed from their tables**: the surveys to check them against are
  ANSUR II (Gordon et al. 2014, *2012 Anthropometric Survey of U.S. Army Personnel*,
  NATICK/TR-15/007; hand length, breadth, thickness at metacarpale III), Greiner 1991 (*Hand
  Anthropometry of U.S. Army Personnel*, NATICK/TR-92/011; finger segment lengths and
  breadths), the 1988 survey's correlation tables (Cheverud et al. 1990, NATICK/TR-90/032), and
  for phalanx proportions Buryanov & Kotiuk 2010 or Alexander 2010.

Correlations within a sex: hand length with breadth 0.65, with palm thickness 0.45, breadth with
thickness 0.5; the ratios are taken independent of the sizes except ``index_ratio`` with
``digit_ratio`` (0.5: a longer index finger raises both) and with ``pinky_ratio`` (0.3). The
mixture's overall correlations are larger (both sexes' means differ along the same direction);
:func:`population_moments` computes them exactly.
Every draw is clipped to :data:`ANTHROPOMETRIC_CLIP` (about +-3 SD of the mixture), so the
moments of the samples are those of the mixture to within sampling error.

The measurements map onto :class:`HandShape` (:func:`measurements_to_shape`): ``hand_length``
directly; ``finger_thickness`` follows the breadth (fingers of broad hands are thicker, plus a
small independent residual) and ``palm_width`` is then solved so that the model's breadth is
the drawn one (:data:`MODEL_BREADTH_RATIO`), ``palm_thickness`` likewise for the thickness
(:data:`MODEL_THICKNESS_RATIO`; caliper readings on sampled subjects match the drawn breadth to
2 % and thickness to 8 %); ``ring_ratio = index_ratio / digit_ratio``. The parameters
that anthropometry does not pin down (thumb, knuckles, spread, flesh, ...) keep v1's clipped
normals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .shape import HandShape

__all__ = [
    "MEASUREMENTS",
    "ANTHROPOMETRIC_TABLE",
    "ANTHROPOMETRIC_CLIP",
    "MODEL_BREADTH_RATIO",
    "MODEL_THICKNESS_RATIO",
    "Measurements",
    "population_moments",
    "sample_measurements",
    "measurements_to_shape",
    "sample_anthropometric_shape",
    "shape_measurements",
]

MEASUREMENTS = ("hand_length", "hand_breadth", "palm_thickness", "digit_ratio", "index_ratio",
                "pinky_ratio")
"""The jointly drawn measurements, in the order of every vector and matrix below (lengths in
metres, ratios unitless)."""

# Per sex: means [6] and SDs [6] (metres / ratios), see the module docstring for the sources.
ANTHROPOMETRIC_TABLE: dict[str, dict[str, tuple[float, ...]]] = {
    "female": {
        "mean": (0.175, 0.075, 0.0250, 0.969, 0.930, 0.780),
        "std": (0.009, 0.004, 0.0020, 0.033, 0.022, 0.028),
    },
    "male": {
        "mean": (0.190, 0.085, 0.0285, 0.957, 0.925, 0.780),
        "std": (0.010, 0.005, 0.0020, 0.032, 0.022, 0.028),
    },
}
"""Means and standard deviations per sex of :data:`MEASUREMENTS` (metres, ratios)."""

# Within-sex correlation matrix (shared by both sexes), order of MEASUREMENTS.
_CORRELATION = np.array([
    [1.00, 0.65, 0.45, 0.00, 0.00, 0.00],
    [0.65, 1.00, 0.50, 0.00, 0.00, 0.00],
    [0.45, 0.50, 1.00, 0.00, 0.00, 0.00],
    [0.00, 0.00, 0.00, 1.00, 0.50, 0.00],
    [0.00, 0.00, 0.00, 0.50, 1.00, 0.30],
    [0.00, 0.00, 0.00, 0.00, 0.30, 1.00],
])

ANTHROPOMETRIC_CLIP: dict[str, tuple[float, float]] = {
    "hand_length": (0.145, 0.225),
    "hand_breadth": (0.060, 0.102),
    "palm_thickness": (0.019, 0.035),
    "digit_ratio": (0.86, 1.07),
    "index_ratio": (0.86, 0.99),
    "pinky_ratio": (0.70, 0.86),
}
"""Plausible range of every measurement (metres, ratios): draws are clipped into it."""

MODEL_BREADTH_RATIO = 0.4605
"""Hand breadth across the metacarpal heads over hand length of the v2 model at
``palm_width = finger_thickness = 1`` (measured on its rest mesh). Of it, the MCP joints' span
(index to little finger, ``0.332 palm_width (0.6 + 0.4 finger_thickness)``) and the knuckles'
flesh outside it (``0.1285 finger_thickness``)."""
_SPAN_RATIO = 0.332
MODEL_THICKNESS_RATIO = 0.149
"""Palm thickness at the metacarpal heads over hand length of the v2 model at
``palm_thickness = finger_thickness = 1`` (measured on its rest mesh): ``0.097 palm_thickness
+ 0.052 finger_thickness`` (the metacarpal heads' part; least squares over six meshes)."""
_HEADS_THICKNESS_RATIO = 0.052

_FEMALE_FRACTION = 0.5


@dataclass(frozen=True)
class Measurements:
    """One drawn adult hand: :data:`MEASUREMENTS` (metres, ratios) and the sex drawn."""

    values: tuple[float, ...]
    """[6] in the order of :data:`MEASUREMENTS`, clipped to :data:`ANTHROPOMETRIC_CLIP`."""
    female: bool

    def __getitem__(self, name: str) -> float:
        return self.values[MEASUREMENTS.index(name)]


def _covariance(sex: str) -> np.ndarray:
    std = np.asarray(ANTHROPOMETRIC_TABLE[sex]["std"])
    return _CORRELATION * std[:, None] * std[None, :]


def population_moments() -> tuple[np.ndarray, np.ndarray]:
    """Exact mean [6] and covariance [6, 6] of the (unclipped) 50/50 mixture of the female and
    male normals: ``mean = sum p_s m_s``, ``cov = sum p_s (C_s + m_s m_s^T) - mean mean^T``."""
    weights = {"female": _FEMALE_FRACTION, "male": 1.0 - _FEMALE_FRACTION}
    means = {s: np.asarray(ANTHROPOMETRIC_TABLE[s]["mean"]) for s in weights}
    mean = sum(w * means[s] for s, w in weights.items())
    second = sum(w * (_covariance(s) + np.outer(means[s], means[s])) for s, w in weights.items())
    return mean, second - np.outer(mean, mean)


def sample_measurements(generator: torch.Generator) -> Measurements:
    """Draw one adult hand's measurements: the sex (50/50), then the sex's multivariate normal
    (a Cholesky factor times six standard normals), clipped to :data:`ANTHROPOMETRIC_CLIP`.

    generator: a seeded ``torch.Generator`` (CPU); the same seed gives the same draw.
    """
    if not isinstance(generator, torch.Generator):
        raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
    female = float(torch.rand((), generator=generator, dtype=torch.float64)) < _FEMALE_FRACTION
    sex = "female" if female else "male"
    normal = torch.randn(len(MEASUREMENTS), generator=generator, dtype=torch.float64).numpy()
    values = np.asarray(ANTHROPOMETRIC_TABLE[sex]["mean"]) + _cholesky(sex) @ normal
    low = np.array([ANTHROPOMETRIC_CLIP[n][0] for n in MEASUREMENTS])
    high = np.array([ANTHROPOMETRIC_CLIP[n][1] for n in MEASUREMENTS])
    return Measurements(values=tuple(float(v) for v in np.clip(values, low, high)), female=female)


def _cholesky(sex: str) -> np.ndarray:
    return np.linalg.cholesky(_covariance(sex))


def _clipped_normal(generator: torch.Generator, mean: float, std: float, low: float,
                    high: float) -> float:
    value = mean + std * float(torch.randn((), generator=generator, dtype=torch.float64))
    return float(min(max(value, low), high))


# v1's clipped normals (mean, std, low, high) for what anthropometry does not pin down.
_FREE_PARAMETERS: dict[str, tuple[float, float, float, float]] = {
    "palm_length": (0.50, 0.012, 0.465, 0.535),
    "thumb_length": (1.0, 0.04, 0.9, 1.1),
    "thumb_angle": (0.72, 0.07, 0.55, 0.9),
    "thumb_base": (1.0, 0.04, 0.9, 1.1),
    "knuckle_size": (1.0, 0.12, 0.72, 1.32),
    "fingertip_taper": (0.74, 0.035, 0.66, 0.84),
    "finger_spread": (1.0, 0.18, 0.75, 1.5),
    "flesh": (1.0, 0.1, 0.8, 1.25),
    "finger_thickness_residual": (0.0, 0.04, -0.1, 0.1),
}


def measurements_to_shape(measured: Measurements, free: dict[str, float]) -> HandShape:
    """The :class:`HandShape` of drawn measurements (mapping in the module docstring).

    measured: from :func:`sample_measurements`; free: values of the parameters anthropometry
    does not fix (the keys of ``_FREE_PARAMETERS``).
    """
    length = measured["hand_length"]
    breadth_ratio = measured["hand_breadth"] / length
    index_ratio = measured["index_ratio"]
    ring_ratio = min(max(index_ratio / measured["digit_ratio"], 0.86), 1.06)
    finger_thickness = float(np.clip(0.5 + 0.5 * breadth_ratio / MODEL_BREADTH_RATIO
                                     + free["finger_thickness_residual"], 0.75, 1.3))
    # The palm width that gives the drawn breadth with these fingers (MODEL_BREADTH_RATIO).
    knuckles = (MODEL_BREADTH_RATIO - _SPAN_RATIO) * finger_thickness
    palm_width = (breadth_ratio - knuckles) / (_SPAN_RATIO * (0.6 + 0.4 * finger_thickness))
    heads = _HEADS_THICKNESS_RATIO * finger_thickness
    thickness_scale = (measured["palm_thickness"] / length - heads) / (
        MODEL_THICKNESS_RATIO - _HEADS_THICKNESS_RATIO)
    values = {name: value for name, value in free.items() if name != "finger_thickness_residual"}
    return HandShape(
        hand_length=length,
        palm_width=float(np.clip(palm_width, 0.75, 1.3)),
        palm_thickness=float(np.clip(thickness_scale, 0.75, 1.3)),
        index_ratio=index_ratio,
        ring_ratio=ring_ratio,
        pinky_ratio=measured["pinky_ratio"],
        finger_thickness=finger_thickness,
        **values,
    )


def sample_anthropometric_shape(generator: torch.Generator) -> HandShape:
    """Draw a random adult hand shape of hand model v2: :func:`sample_measurements`, then the
    free parameters' clipped normals, mapped by :func:`measurements_to_shape`.

    generator: a seeded ``torch.Generator`` (CPU); the same seed gives the same shape.
    """
    measured = sample_measurements(generator)
    free = {name: _clipped_normal(generator, *spec) for name, spec in _FREE_PARAMETERS.items()}
    return measurements_to_shape(measured, free)


def shape_measurements(shape: HandShape) -> dict[str, float]:
    """The measurements a v2 shape stands for (inverse of :func:`measurements_to_shape` for
    unclipped values): hand length, breadth and palm thickness (metres), 2D:4D."""
    length = shape.hand_length
    return {
        "hand_length": length,
        "hand_breadth": length * (_SPAN_RATIO * shape.palm_width
                                  * (0.6 + 0.4 * shape.finger_thickness)
                                  + (MODEL_BREADTH_RATIO - _SPAN_RATIO) * shape.finger_thickness),
        "palm_thickness": length * ((MODEL_THICKNESS_RATIO - _HEADS_THICKNESS_RATIO)
                                    * shape.palm_thickness
                                    + _HEADS_THICKNESS_RATIO * shape.finger_thickness),
        "digit_ratio": shape.index_ratio / shape.ring_ratio,
        "index_ratio": shape.index_ratio,
        "pinky_ratio": shape.pinky_ratio,
    }

