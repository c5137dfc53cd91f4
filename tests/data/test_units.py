"""The length unit of a hand's points, from the size of a hand (lisa_hand.data.units)."""

import numpy as np
import pytest
import torch

from lisa_hand.data.units import (
    HAND_DIAGONAL_M,
    bounding_diagonal,
    decide_length_unit,
    detect_length_unit,
)


def _box(diagonal: float) -> np.ndarray:
    """Corners of a cube whose diagonal is ``diagonal``."""
    side = diagonal / np.sqrt(3.0)
    return np.array([[x, y, z] for x in (0, side) for y in (0, side) for z in (0, side)])


def test_bounding_diagonal_ignores_non_finite_points_and_takes_tensors():
    points = np.vstack([_box(0.2), [np.nan, 0.0, 0.0]])
    assert bounding_diagonal(points) == pytest.approx(0.2)
    assert bounding_diagonal(torch.from_numpy(points)) == pytest.approx(0.2)
    with pytest.raises(ValueError, match="no point with finite coordinates"):
        bounding_diagonal(np.full((3, 3), np.nan))


@pytest.mark.parametrize(("diagonal", "unit"), [
    (0.2, "m"), (0.06, "m"), (0.44, "m"),
    (25.0, "cm"), (12.0, "cm"),  # a hand in centimetres (was read as millimetres: 10x small)
    (180.0, "mm"), (60.0, "mm"), (400.0, "mm"),
])
def test_auto_reads_metres_centimetres_and_millimetres(diagonal, unit):
    assert detect_length_unit(_box(diagonal)) == unit
    decided = decide_length_unit(_box(diagonal), name="hand.ply", what="the cloud")
    assert decided.unit == unit and decided.detected
    assert decided.metres_per_unit * diagonal == pytest.approx(diagonal * {
        "m": 1.0, "cm": 0.01, "mm": 0.001}[unit])
    if unit == "m":
        assert decided.note is None
    else:
        name = "centimetres" if unit == "cm" else "millimetres"
        assert decided.note.startswith(f"the cloud is {diagonal:.4g} units across: read as {name}")


def test_no_size_is_a_hand_in_two_units():
    low, high = HAND_DIAGONAL_M
    assert high / low < 10.0
    for diagonal in np.geomspace(1e-3, 1e4, 400):
        fits = [u for u, s in (("m", 1.0), ("cm", 1e-2), ("mm", 1e-3))
                if low <= diagonal * s <= high]
        assert len(fits) <= 1
        assert detect_length_unit(_box(diagonal)) == (fits[0] if fits else None)


@pytest.mark.parametrize(("diagonal", "message"), [
    (47.0, r"scan\.npy: the cloud is 47 units across, which fits no unit .*pass --units cm "
           r"\(units='cm'\) or --units mm"),
    (0.005, r"too small for a hand in any unit"),
    (5e4, r"too large for a hand in any unit .*crop it to the hand"),
])
def test_auto_refuses_sizes_that_fit_no_unit(diagonal, message):
    with pytest.raises(ValueError, match=message):
        decide_length_unit(_box(diagonal), name="scan.npy", what="the cloud")


@pytest.mark.parametrize(("diagonal", "unit"), [(0.8, "m"), (1.5, "m"), (800.0, "mm"),
                                                (1500.0, "mm")])
def test_auto_reads_a_scan_larger_than_a_hand_in_the_one_unit_that_fits(diagonal, unit):
    # A scan with the forearm (0.8 m) cannot be centimetres (8 mm) or millimetres: read in the
    # one unit that makes it a possible hand scan, and say so.
    decided = decide_length_unit(_box(diagonal), name="scan.npy", what="the cloud")
    assert decided.unit == unit and decided.detected
    assert decided.note is not None and "the only unit" in decided.note


def test_a_given_unit_must_make_a_possible_hand():
    assert decide_length_unit(_box(0.8), "m").unit == "m"  # an arm in the scan: allowed
    given = decide_length_unit(_box(25.0), "cm")
    assert given.unit == "cm" and not given.detected and given.note is None
    with pytest.raises(ValueError, match=r"mm\.ply: the hand is 170 units across: as metres "
                                         r"that is 170 m, too large for a hand .*looks like "
                                         r"millimetres: pass --units mm"):
        decide_length_unit(_box(170.0), "m", name="mm.ply")
    with pytest.raises(ValueError, match=r"as millimetres that is 0\.2 mm, too small for a hand"
                                         r".*looks like metres: pass --units m"):
        decide_length_unit(_box(0.2), "mm")
    with pytest.raises(ValueError, match="units must be one of auto, m, cm, mm, got 'inch'"):
        decide_length_unit(_box(0.2), "inch")
