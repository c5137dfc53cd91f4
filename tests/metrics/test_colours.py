"""A fitted mesh's colour errors (:func:`lisa_hand.metrics.colours.colour_errors`): errors of
known size on a sphere seen from one side, apart where the scan saw it and where it did not."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from lisa_hand.geometry.meshing import Mesh
from lisa_hand.metrics.colours import colour_errors


def test_colour_errors_measure_seen_and_hidden_parts_apart():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    colours = np.full((len(sphere.vertices), 3), 100, np.uint8)
    truth = Mesh(sphere.vertices, sphere.faces, colors=colours)
    fitted = colours.astype(np.int64).copy()
    upper = sphere.vertices[:, 2] > 0
    fitted[upper] += 6  # off by 6 levels where seen, by 20 where hidden
    fitted[~upper] -= 20
    points = sphere.vertices[upper] * 1.0001  # the scan: the upper half's vertices
    errors = colour_errors(truth, np.asarray(sphere.vertices), fitted.astype(np.uint8), points,
                           {"flat": np.full(3, 110 / 255)})
    assert errors["fit"]["seen_mae"] == pytest.approx(6.0)
    assert errors["fit"]["hidden_mae"] == pytest.approx(20.0)
    assert errors["fit"]["seen_psnr"] == pytest.approx(-20 * math.log10(6 / 255))
    assert errors["flat"]["seen_mae"] == pytest.approx(10.0)
    assert errors["fit"]["seen_share"] == pytest.approx(upper.mean(), abs=0.02)
    # Vertices the fitted surface does not reach (over 3 mm away) are not counted.
    far = colour_errors(truth, np.asarray(sphere.vertices) + 0.01, fitted.astype(np.uint8),
                        points, {})
    assert math.isnan(far["fit"]["seen_mae"]) and math.isnan(far["fit"]["hidden_mae"])
