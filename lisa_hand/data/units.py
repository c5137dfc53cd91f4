"""The length unit of a hand's coordinates in a file: metres, centimetres or millimetres.

Files rarely say their unit. A hand is a known size, so its bounding box tells: the diagonal of
a hand's axis-aligned box is about 0.1-0.3 m, that is 10-30 in centimetres and 100-300 in
millimetres. :func:`decide_length_unit` reads the unit from that size, or checks a unit the user
gave, and refuses with one line (naming the file and the ``--units`` to pass) when the size fits
no unit. The readers of point clouds
(:func:`lisa_hand.fitting.points.inputs.prepare_point_cloud`), of ground-truth meshes
(:func:`lisa_hand.fitting.outputs.read_ground_truth`) and ``lisa metrics``
(:func:`lisa_hand.metrics.compare_mesh_files`) all use this one rule.

Two ranges of the diagonal, in metres:

* :data:`HAND_DIAGONAL_M` (0.05-0.45 m): what ``units="auto"`` reads as a hand. Wider than a
  hand (partial scans, a bit of wrist or background) but under a factor 10 wide, so that no
  size is a hand in two units: auto reads 0.05-0.45 as metres, 5-45 as centimetres, 50-450 as
  millimetres. Outside those, a size that only one unit makes a possible hand (below) is read
  in that unit with a note (a 0.6 m scan with the forearm is metres: 6 mm or 0.6 mm is no
  hand), and a size two units could explain is refused (a 47-unit box could be 47 cm or 47 mm).
* :data:`POSSIBLE_DIAGONAL_M` (0.02-2 m): what a unit given explicitly may make of the hand (a
  fingertip-sized partial scan up to a scan with the arm and background). Outside it the unit is
  wrong: ``--units m`` on a millimetre file would read a 170 m hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "LENGTH_UNITS",
    "UNIT_CHOICES",
    "UNIT_NAMES",
    "HAND_DIAGONAL_M",
    "POSSIBLE_DIAGONAL_M",
    "LengthUnit",
    "bounding_diagonal",
    "detect_length_unit",
    "decide_length_unit",
]

LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
"""Unit -> metres per unit."""

UNIT_CHOICES = ("auto", "m", "cm", "mm")
"""What a ``units`` argument (``--units``) accepts: a unit, or "auto" (guessed from the size)."""

UNIT_NAMES = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}
"""Unit -> its name in messages."""

HAND_DIAGONAL_M = (0.05, 0.45)
"""Bounding-box diagonals (metres) that ``units="auto"`` reads as a hand (module docstring)."""

POSSIBLE_DIAGONAL_M = (0.02, 2.0)
"""Bounding-box diagonals (metres) a given unit may make of a hand (module docstring)."""

_HAND_SIZE = "a hand is about 0.1-0.3 m, 10-30 cm or 100-300 mm across"


@dataclass(frozen=True)
class LengthUnit:
    """The unit a file's coordinates were read in (:func:`decide_length_unit`)."""

    unit: str
    """ "m", "cm" or "mm"."""
    detected: bool
    """True when the unit was guessed from the size (``units="auto"``)."""
    diagonal: float
    """Bounding-box diagonal of the points, in the file's units."""
    note: str | None
    """One sentence when the guess converted the points (a unit other than metres) or read a
    size outside a hand's, else None; without the file's name, which the caller puts in front."""

    @property
    def metres_per_unit(self) -> float:
        """Multiply the file's coordinates by this to get metres."""
        return LENGTH_UNITS[self.unit]


def _as_points(points: Any) -> np.ndarray:
    if hasattr(points, "detach") and hasattr(points, "cpu"):  # a torch tensor, any device
        points = points.detach().cpu().numpy()
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {list(array.shape)}")
    return array


def bounding_diagonal(points: Any) -> float:
    """Length of the diagonal of the axis-aligned box around the finite points.

    points: [N, 3] (numpy array, or torch tensor on any device), any unit -> the same unit.
    Raises ValueError when no point is finite.
    """
    array = _as_points(points)
    finite = array[np.isfinite(array).all(axis=1)]
    if len(finite) == 0:
        raise ValueError("points: no point with finite coordinates")
    return float(np.linalg.norm(finite.max(axis=0) - finite.min(axis=0)))


def _units_that_fit(diagonal: float, bounds: tuple[float, float]) -> list[str]:
    low, high = bounds
    return [unit for unit, scale in LENGTH_UNITS.items() if low <= diagonal * scale <= high]


def detect_length_unit(points: Any) -> str | None:
    """The unit in which ``points`` are the size of a hand, or None when no unit fits.

    points: [N, 3] -> "m", "cm", "mm" (the bounding-box diagonal within :data:`HAND_DIAGONAL_M`
    in that unit; at most one unit can fit) or None.
    """
    fits = _units_that_fit(bounding_diagonal(points), HAND_DIAGONAL_M)
    return fits[0] if fits else None


def _in_metres(size_m: float) -> str:
    return f"{size_m * 1e3:.3g} mm" if size_m < 0.1 else f"{size_m:.3g} m"


def _units_option(units: list[str]) -> str:
    return " or ".join(f"--units {unit} (units={unit!r})" for unit in units)


def decide_length_unit(points: Any, units: str = "auto", *, name: str = "points",
                       what: str = "the hand") -> LengthUnit:
    """Decide (``units="auto"``) or check (a given unit) the length unit of a hand's points.

    points: [N, 3] in the file's unit (non-finite rows are ignored); units: one of
    :data:`UNIT_CHOICES`; name: the file, for messages; what: how messages call the points
    ("the cloud", "the mesh").

    auto: the unit in which the bounding-box diagonal is within :data:`HAND_DIAGONAL_M`, with a
    note when it is not metres; when none is, the one unit that makes a possible hand
    (:data:`POSSIBLE_DIAGONAL_M`), with a note; when two do, a ValueError naming the ``--units``
    that would, or saying that no unit can.
    A given unit: a ValueError when it makes the diagonal leave :data:`POSSIBLE_DIAGONAL_M`,
    naming the unit that looks right.
    """
    if units not in UNIT_CHOICES:
        raise ValueError(f"units must be one of {', '.join(UNIT_CHOICES)}, got {units!r}")
    diagonal = bounding_diagonal(points)
    across = f"{name}: {what} is {diagonal:.4g} units across"
    if units == "auto":
        fits = _units_that_fit(diagonal, HAND_DIAGONAL_M)
        if fits:
            unit = fits[0]
            note = None if unit == "m" else (
                f"{what} is {diagonal:.4g} units across: read as {UNIT_NAMES[unit]} and "
                f"converted to metres (pass --units m, cm or mm to choose)")
            return LengthUnit(unit=unit, detected=True, diagonal=diagonal, note=note)
        possible = _units_that_fit(diagonal, POSSIBLE_DIAGONAL_M)
        if len(possible) == 1:  # larger or smaller than a hand, but possible in one unit only
            unit = possible[0]
            size = _in_metres(diagonal * LENGTH_UNITS[unit])
            note = (f"{what} is {diagonal:.4g} units across, {size} as {UNIT_NAMES[unit]}, "
                    f"the only unit that makes it a possible hand scan: "
                    f"read as {UNIT_NAMES[unit]} (pass --units to choose)")
            return LengthUnit(unit=unit, detected=True, diagonal=diagonal, note=note)
        if possible:
            raise ValueError(f"{across}, which fits no unit ({_HAND_SIZE}); pass "
                             f"{_units_option(possible)} to say which it is")
        if diagonal * LENGTH_UNITS["m"] < POSSIBLE_DIAGONAL_M[0]:
            raise ValueError(f"{across}, too small for a hand in any unit "
                             f"({_in_metres(diagonal)} even in metres; {_HAND_SIZE})")
        raise ValueError(f"{across}, too large for a hand in any unit "
                         f"({_in_metres(diagonal * LENGTH_UNITS['mm'])} even in millimetres; "
                         f"{_HAND_SIZE}): crop it to the hand")
    size = diagonal * LENGTH_UNITS[units]
    low, high = POSSIBLE_DIAGONAL_M
    if not low <= size <= high:
        looks = _units_that_fit(diagonal, HAND_DIAGONAL_M) or _units_that_fit(
            diagonal, POSSIBLE_DIAGONAL_M)
        advice = (f"it looks like {UNIT_NAMES[looks[0]]}: pass {_units_option(looks[:1])}"
                  if looks else "crop it to the hand or check the file")
        raise ValueError(f"{across}: as {UNIT_NAMES[units]} that is {_in_metres(size)}, too "
                         f"{'small' if size < low else 'large'} for a hand ({_HAND_SIZE}); "
                         f"{advice}")
    return LengthUnit(unit=units, detected=False, diagonal=diagonal, note=None)
