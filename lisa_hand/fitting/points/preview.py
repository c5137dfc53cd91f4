"""A picture of a point-cloud fit: ``preview.png`` of ``lisa fit-points``.

Three views of the fitted surface (grey, lit from the camera) with the scan's points drawn on it
where the camera sees them, each coloured by its distance to the fitted surface (blue under
1 mm, through green and yellow, red from 5 mm: where the fit misses the scan; grey: points the
fit left out beyond the wrist). The first view looks from the scan's sensor when the fit had one
(``--viewpoint``, given or found), else along the fitted hand's thinnest direction (onto its
palm or its back); the second is turned 90 degrees about the image's vertical axis, the third
looks from behind the first (for a one-view scan: the side the sensor did not see, the fit's
guess). The hand's longest direction (wrist to fingertips) is kept upright in the images.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["fit_preview", "distance_colors"]

_FOV_DEG = 30.0
_NEAR_M = 0.002  # a point this far in front of the surface's depth still shows
_SCALE_MM = 5.0  # red from here


def distance_colors(distance_mm: np.ndarray) -> np.ndarray:
    """Colours [N, 3] float in [0, 1] of distances [N] mm: blue at 0-1, green at 2.3, yellow at
    3.7, red from 5 (a piecewise-linear ramp)."""
    stops = np.array([[0.15, 0.35, 1.0], [0.15, 0.35, 1.0], [0.1, 0.8, 0.2], [1.0, 0.85, 0.1],
                      [0.95, 0.1, 0.1]])
    at = np.array([0.0, 1.0, 2.33, 3.67, _SCALE_MM])
    value = np.clip(np.asarray(distance_mm, np.float64), 0.0, _SCALE_MM)
    return np.stack([np.interp(value, at, stops[:, c]) for c in range(3)], axis=-1)


def _axes(vertices: np.ndarray, viewpoint: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(unit direction [3] from the hand's centre towards the first view's camera, unit image-up
    [3] across it): the sensor's direction, or the thinnest principal axis; up along the
    longest principal axis (the next one when that looks along the view: of two orthogonal
    axes one is always at least 45 degrees off it)."""
    centre = vertices.mean(0)
    _, _, axes = np.linalg.svd(vertices - centre, full_matrices=False)
    toward = axes[2] if viewpoint is None else np.asarray(viewpoint, np.float64) - centre
    toward = toward / max(np.linalg.norm(toward), 1e-12)
    across = axes[0] - (axes[0] @ toward) * toward
    if np.linalg.norm(across) <= 0.3:
        across = axes[1] - (axes[1] @ toward) * toward
    return toward, across / np.linalg.norm(across)


def _rotated(vector: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """``vector`` [3] turned by ``angle`` radians about the unit ``axis`` [3]."""
    import torch

    from ...geometry import axis_angle_to_matrix

    return axis_angle_to_matrix(torch.from_numpy(angle * axis)).numpy() @ vector


def _camera(vertices: np.ndarray, toward: np.ndarray, up: np.ndarray, size: int):
    """A square camera [size px] looking at the surface from ``toward`` (unit [3], from its
    centre), ``up`` upright, far enough to see all of it."""
    import torch

    from ...geometry.cameras import Camera, intrinsics_from_fov, look_at

    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    distance = 1.15 * radius / math.sin(math.radians(0.5 * _FOV_DEG))
    R, t = look_at(torch.from_numpy(centre + distance * toward), torch.from_numpy(centre),
                   torch.from_numpy(up))
    return Camera(K=intrinsics_from_fov(_FOV_DEG, size, size, dtype=torch.float64), R=R, t=t,
                  width=size, height=size)


def _with_points(view, camera, points: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """One panel [size, size, 3] float: the rendered ``view`` with the ``points`` [N, 3] that
    ``camera`` sees (not behind the surface) drawn over it as dots of ``colors`` [N, 3]."""
    import torch

    from ...geometry.cameras import project_points

    size = camera.width
    image = view.rgb.astype(np.float64).copy()
    pixels, depth = project_points(camera.K, camera.R, camera.t, torch.from_numpy(points))
    u, v = np.floor(pixels.numpy()).astype(np.int64).T
    z = depth.numpy()
    inside = (z > 0) & (u >= 0) & (u < size) & (v >= 0) & (v < size)
    u, v, z, colors = u[inside], v[inside], z[inside], colors[inside]
    seen = ~view.mask[v, u] | (z <= view.depth[v, u] + _NEAR_M)
    order = np.argsort(-z[seen])  # far first, so that the nearest dot is drawn last
    u, v, colors = u[seen][order], v[seen][order], colors[seen][order]
    dot = max(1, size // 240)
    for du in range(-dot, dot + 1):
        for dv in range(-dot, dot + 1):
            if du * du + dv * dv <= dot * dot:
                image[np.clip(v + dv, 0, size - 1), np.clip(u + du, 0, size - 1)] = colors
    return image


def fit_preview(vertices, faces, points, distances_mm, kept=None, viewpoint=None,
                size: int = 400) -> np.ndarray:
    """The picture of a fit (see the module docstring).

    vertices: [V, 3] metres and faces: [F, 3] of the fitted surface; points: [N, 3] metres, the
    scan; distances_mm: [N] each point's distance to the surface; kept: [N] bool, the points the
    fit kept (others grey), None: all; viewpoint: [3] metres, the sensor, or None; size: pixels
    of each square panel. -> [size + legend, 3 size, 3] uint8 RGB.
    """
    from ...data.images import render_views
    from ...data.shading import ShadingConfig

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    points = np.asarray(points, np.float64)
    colors = distance_colors(distances_mm)
    if kept is not None:
        colors[~np.asarray(kept, bool)] = 0.55
    toward, up = _axes(vertices, viewpoint)
    cameras = [_camera(vertices, _rotated(toward, up, angle), up, size)
               for angle in (0.0, 0.5 * math.pi, math.pi)]
    shading = ShadingConfig(ambient=0.3, diffuse=0.7, light_directions=((0.0, -0.3, -1.0),),
                            background=(1.0, 1.0, 1.0))
    views = render_views(vertices, faces, cameras, np.array([0.72, 0.72, 0.72]),
                         shading=shading)
    picture = np.concatenate([_with_points(view, camera, points, colors)
                              for view, camera in zip(views, cameras, strict=True)], axis=1)
    return _with_labels(picture, size, viewpoint is not None)


def _with_labels(picture: np.ndarray, size: int, from_sensor: bool) -> np.ndarray:
    """The panels [size, 3 size, 3] float with their titles and the colour legend below."""
    from PIL import Image, ImageDraw

    legend = 28
    canvas = np.ones((size + legend, picture.shape[1], 3))
    canvas[:size] = picture
    ramp = np.linspace(0.0, _SCALE_MM, 200)
    x0 = picture.shape[1] - 260
    canvas[size + 8:size + 20, x0:x0 + 200] = distance_colors(ramp)[None]
    image = Image.fromarray((np.clip(canvas, 0, 1) * 255 + 0.5).astype(np.uint8))
    draw = ImageDraw.Draw(image)
    first = "from the sensor" if from_sensor else "front"
    for index, title in enumerate((first, "turned 90 degrees", "from behind")):
        draw.text((index * size + 8, 6), title, fill=(0, 0, 0))
    draw.text((8, size + 8), "scan points by their distance to the fitted surface (grey: left "
              "out: beyond the wrist, on a support or apart from the hand)", fill=(0, 0, 0))
    draw.text((x0 - 14, size + 8), "0", fill=(0, 0, 0))
    draw.text((x0 + 204, size + 8), f"{_SCALE_MM:g}+ mm", fill=(0, 0, 0))
    return np.asarray(image)
