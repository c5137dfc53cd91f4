"""The colour benchmark's measure (``lisa_hand.bench.colours``): errors of known size on a sphere
seen from one side, and a coloured scan whose colours are the hand's true albedo."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from lisa_hand.bench.colours import colour_errors, coloured_scan
from lisa_hand.geometry.meshing import Mesh


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


def test_a_coloured_scan_carries_the_hands_albedo(tmp_path):
    from lisa_hand.fitting.points.colours import read_point_colours
    from lisa_hand.fitting.points.inputs import read_point_cloud

    path, truth, points = coloured_scan(0, "s002", True, tmp_path)
    read, _ = read_point_cloud(path)
    assert np.allclose(read, points, atol=1e-6) and len(points) == 8000
    colours = read_point_colours(path, len(read))
    # Each point's colour is the true mesh's near it (albedo varies slowly over the skin).
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(truth.vertices).query(points)
    difference = np.abs(colours - truth.colors[nearest] / 255.0).mean(1)
    assert np.median(difference) < 0.01
