"""``preview.png`` of a point-cloud fit (``lisa_hand.fitting.points.preview``): a sphere and
points on its far side, seen from a sensor on its near side."""

from __future__ import annotations

import numpy as np
import trimesh

from lisa_hand.fitting.points.preview import distance_colors, fit_preview

SIZE = 120


def _blue(panel: np.ndarray) -> int:
    """Pixels of the 0-1 mm colour (blue) in an RGB uint8 panel."""
    r, g, b = (panel[..., c].astype(int) for c in range(3))
    return int(((b > 200) & (r < 80) & (g < 130)).sum())


def test_distance_colours_run_from_blue_to_red():
    colors = distance_colors(np.array([0.0, 0.5, 5.0, 50.0]))
    assert np.allclose(colors[0], colors[1]) and colors[0].argmax() == 2  # blue up to 1 mm
    assert np.allclose(colors[2], colors[3]) and colors[2].argmax() == 0  # red from 5 mm
    assert ((colors >= 0) & (colors <= 1)).all()


def test_points_behind_the_surface_show_only_from_behind():
    """Points on the far half of a sphere, the sensor on the near side: the first panel (from
    the sensor) shows none of them, the third (from behind) shows them; left out of the fit
    (``kept`` False) they are grey, not blue."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    vertices = np.asarray(sphere.vertices) + np.array([0.0, 0.0, 0.4])
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(3000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[:, 2] = np.abs(directions[:, 2])  # the far side: +z, away from the origin
    points = np.array([0.0, 0.0, 0.4]) + 0.0502 * directions
    picture = fit_preview(vertices, sphere.faces, points, np.zeros(len(points)),
                          viewpoint=np.zeros(3), size=SIZE)
    assert picture.shape[1] == 3 * SIZE and picture.shape[0] > SIZE and picture.dtype == np.uint8
    first, _, behind = (picture[:SIZE, k * SIZE:(k + 1) * SIZE] for k in range(3))
    assert _blue(first) == 0
    assert _blue(behind) > 0.2 * SIZE * SIZE * 0.25  # a good part of the disc
    grey = fit_preview(vertices, sphere.faces, points, np.zeros(len(points)),
                       kept=np.zeros(len(points), bool), viewpoint=np.zeros(3), size=SIZE)
    assert _blue(grey[:SIZE, 2 * SIZE:]) == 0
