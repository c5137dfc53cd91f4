"""Colour errors of a fitted mesh against a true coloured mesh, where a scan saw the surface and
where it did not (:func:`colour_errors`).

A fit from a coloured scan (``lisa fit-points SCAN.ply``) knows the colours the scan saw and must
guess the rest (the hidden side of a one-sided scan), so one mean error would mix two different
things. Measured at the true mesh's vertices within :data:`NEAR_M` of the fitted mesh (the others
are left out: the fit's surface does not reach them): the colour of the nearest fitted vertex
against the true one, as the mean absolute error in 8-bit levels and the PSNR in dB (colours in
[0, 1]), over the vertices within :data:`NEAR_M` of a scan point ("seen") and over the others
("hidden"). ``python -m benchmarks colours`` (from the repository root) reports them for held-out
hands.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["NEAR_M", "colour_errors"]

NEAR_M = 0.003
"""Metres: a true vertex counts when a fitted vertex lies this near; it is seen when a scan point
does."""


def _psnr(error: np.ndarray) -> float:
    """PSNR (dB) of colour differences [M, 3] in [0, 1]."""
    mse = float(np.mean(error ** 2))
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def colour_errors(truth, vertices: np.ndarray, colours: np.ndarray, points: np.ndarray,
                  references: dict[str, np.ndarray], others: dict[str, np.ndarray] | None = None
                  ) -> dict[str, dict[str, float]]:
    """Errors of a fitted mesh's colours against a true coloured mesh's, apart on the surface a
    scan saw and on the rest (module docstring).

    truth: the true mesh (``vertices`` [V, 3] metres, ``colors`` [V, 3] uint8); vertices: [W,
    3] metres and colours: [W, 3] uint8 of the fitted mesh; points: the scan's [N, 3] metres;
    references: name -> [3] colour in [0, 1] given to every vertex (a baseline such as the
    scan's mean colour); others: name -> [W, 3] uint8, other colourings of the fitted mesh.
    -> {"fit" and each reference and other: {"seen_mae", "seen_psnr", "hidden_mae",
    "hidden_psnr" (8-bit levels, dB; NaN where no vertex), "seen_share" (the seen share of the
    counted vertices)}}."""
    from scipy.spatial import cKDTree

    true_vertices = np.asarray(truth.vertices, np.float64)
    true_colours = np.asarray(truth.colors, np.float64) / 255.0
    distance, nearest = cKDTree(vertices).query(true_vertices)
    on = distance <= NEAR_M
    seen = cKDTree(points).query(true_vertices)[0] <= NEAR_M
    guesses = {name: np.asarray(value, np.float64)[nearest] / 255.0
               for name, value in {"fit": colours, **(others or {})}.items()}
    guesses.update({name: np.broadcast_to(value, true_colours.shape)
                    for name, value in references.items()})
    result = {}
    for name, guess in guesses.items():
        row = {"seen_share": float(seen[on].mean()) if on.any() else math.nan}
        for part, where in (("seen", on & seen), ("hidden", on & ~seen)):
            error = guess[where] - true_colours[where]
            row[f"{part}_mae"] = float(255.0 * np.abs(error).mean()) if where.any() else math.nan
            row[f"{part}_psnr"] = _psnr(error) if where.any() else math.nan
        result[name] = row
    return result
