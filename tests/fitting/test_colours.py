"""A coloured scan's colours on the fitted mesh (``lisa_hand.fitting.points.colours``): colours
read as stored in each format, the harmonic fill against a second (iterative) solution, the
transfer on a sphere scanned from one side, and a depth image's colour image."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.data.depth import DepthFrame, read_depth_cloud
from lisa_hand.fitting.points.colours import (
    MIN_RADIUS_M,
    as_unit_colours,
    colour_radius,
    depth_point_colours,
    harmonic_fill,
    read_point_colours,
    transfer_colours,
)
from lisa_hand.fitting.points.inputs import read_point_cloud
from lisa_hand.geometry.cameras import Camera


def test_stored_colours_become_unit_floats():
    assert np.allclose(as_unit_colours(np.array([[255, 0, 51]], np.uint8)), [[1.0, 0.0, 0.2]])
    assert np.allclose(as_unit_colours(np.array([[65535, 0, 0, 7]], np.uint16)), [[1, 0, 0]])
    assert np.allclose(as_unit_colours(np.array([[0.5, 0.25, 1.0]])), [[0.5, 0.25, 1.0]])
    assert np.allclose(as_unit_colours(np.array([[255.0, 127.5, 0.0]])), [[1.0, 0.5, 0.0]])
    assert as_unit_colours(np.zeros((4, 3))).dtype == np.float32
    for bad, said in ((np.zeros((4, 2)), "shape [N, 3]"), (np.array([[-1.0, 0, 0]]),
                      "not negative"), (np.array([[300.0, 0, 0]]), "reach 300"),
                      (np.array([[np.nan, 0, 0]]), "finite")):
        with pytest.raises(ValueError, match=re.escape(said)):
            as_unit_colours(bad, "scan.ply")


def _jacobi(faces: np.ndarray, values: np.ndarray, known: np.ndarray, steps: int = 20000):
    """The harmonic fill by repeated neighbour averaging (a second implementation)."""
    neighbours = [set() for _ in range(len(values))]
    for a, b, c in faces:
        neighbours[a] |= {b, c}
        neighbours[b] |= {a, c}
        neighbours[c] |= {a, b}
    lists = [np.array(sorted(n)) for n in neighbours]
    current = np.where(known[:, None], values, 0.0)
    for _ in range(steps):
        averaged = np.stack([current[n].mean(0) for n in lists])
        current = np.where(known[:, None], values, averaged)
    return current


def test_the_harmonic_fill_matches_neighbour_averaging_and_keeps_the_known_values():
    grid = trimesh.creation.box().subdivide().subdivide()  # 98 vertices, one closed piece
    vertices, faces = np.asarray(grid.vertices), np.asarray(grid.faces)
    known = vertices[:, 0] > 0.2
    values = np.stack([vertices[:, 1] ** 2, np.sin(3 * vertices[:, 2]), vertices[:, 0]], 1)
    filled = harmonic_fill(faces, values, known)
    assert np.array_equal(filled[known], values[known])
    assert np.allclose(filled, _jacobi(faces, values, known, steps=3000), atol=1e-6)
    # The maximum principle: nothing beyond the known values' range.
    assert filled[~known].min() >= values[known].min() - 1e-9
    assert filled[~known].max() <= values[known].max() + 1e-9
    # A second piece that touches no known vertex takes their mean; all known: unchanged.
    other = faces + len(vertices)
    both = harmonic_fill(np.concatenate([faces, other]), np.concatenate([values, values]),
                         np.concatenate([known, np.zeros(len(vertices), bool)]))
    assert np.allclose(both[len(vertices):], values[known].mean(0))
    assert np.array_equal(harmonic_fill(faces, values, np.ones(len(values), bool)), values)
    with pytest.raises(ValueError, match="at least one known"):
        harmonic_fill(faces, values, np.zeros(len(values), bool))


def test_a_sphere_seen_from_one_side_takes_its_colours_and_fills_the_rest():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    rng = np.random.default_rng(0)
    points = sphere.sample(20000, seed=0)
    points = points[points[:, 2] > 0.0]  # the upper half seen
    points = points + rng.normal(scale=2e-4, size=points.shape)

    def paint(at):  # red along x, green along y, blue constant
        return np.stack([0.5 + 5 * at[:, 0], 0.5 + 5 * at[:, 1], np.full(len(at), 0.3)], 1)

    from scipy.spatial import cKDTree

    found = transfer_colours(vertices, faces, points, paint(points))
    assert found.radius_m == colour_radius(points)
    assert MIN_RADIUS_M <= found.radius_m < 0.005
    assert np.array_equal(found.seen, cKDTree(points).query(vertices)[0] <= found.radius_m)
    seen = found.seen & (vertices[:, 2] > 0.005)
    error = np.abs(found.colors[seen] / 255.0 - paint(vertices[seen]))
    assert error.max() < 0.03  # a linear colour, averaged near each vertex, 8-bit rounded
    hidden = ~found.seen
    assert hidden.mean() > 0.4
    # The unseen half: within the seen colours' range, and smooth (the harmonic fill).
    lower = found.colors[hidden].astype(float)
    assert lower.min(0)[0] >= found.colors[found.seen, 0].min() - 1
    assert np.allclose(lower[:, 2], round(0.3 * 255), atol=1)
    assert transfer_colours(vertices + 1.0, faces, points, paint(points)) is None


def test_colours_are_read_from_each_format(tmp_path):
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.05, 0.05, size=(50, 3))
    colours = rng.integers(0, 256, size=(50, 3)).astype(np.uint8)
    trimesh.PointCloud(points, colors=colours).export(tmp_path / "cloud.ply")
    np.savez(tmp_path / "cloud.npz", points=points, colors=colours)
    with open(tmp_path / "cloud.obj", "w", encoding="utf-8") as handle:
        for point, colour in zip(points, colours / 255.0, strict=True):
            handle.write("v " + " ".join(f"{v:.6f}" for v in (*point, *colour)) + "\n")
    box = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    painted = np.tile([200, 100, 50, 255], (len(box.vertices), 1))
    painted[box.vertices[:, 0] > 0, 1] = 220  # green on the +x half
    box.visual.vertex_colors = painted
    box.export(tmp_path / "box.glb")
    for name in ("cloud.ply", "cloud.npz", "cloud.obj"):
        read, _ = read_point_cloud(tmp_path / name)
        assert np.allclose(read, points, atol=1e-5)
        assert np.allclose(read_point_colours(tmp_path / name, len(read)), colours / 255.0,
                           atol=1e-5), name
    read, _ = read_point_cloud(tmp_path / "box.glb")
    expected = np.where(read[:, :1] > 0, [200, 220, 50], [200, 100, 50]) / 255.0
    assert np.allclose(read_point_colours(tmp_path / "box.glb", len(read)), expected)
    # A textured mesh (a phone scan's GLB): the texture sampled at each vertex, here a left
    # half of one colour and a right half of another.
    from PIL import Image

    textured = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    pixels = np.zeros((4, 4, 3), np.uint8)
    pixels[:, :2], pixels[:, 2:] = (30, 160, 90), (230, 40, 10)
    right = np.arange(len(textured.vertices)) % 2 == 1
    uv = np.c_[np.where(right, 0.8, 0.2), np.full(len(right), 0.5)]
    textured.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(pixels))
    textured.export(tmp_path / "textured.glb")
    read, _ = read_point_cloud(tmp_path / "textured.glb")
    which = np.array([np.argmin(np.linalg.norm(textured.vertices - r, axis=1)) for r in read])
    expected = np.where(right[which, None], [230, 40, 10], [30, 160, 90]) / 255.0
    assert np.allclose(read_point_colours(tmp_path / "textured.glb", len(read)), expected,
                       atol=3 / 255)
    # One colour for the whole mesh (a material's, as the WebXR hand's GLB has): no colours.
    uniform = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    uniform.visual.vertex_colors = np.tile([200, 100, 50, 255], (len(uniform.vertices), 1))
    uniform.export(tmp_path / "uniform.glb")
    assert read_point_colours(tmp_path / "uniform.glb", len(read)) is None
    # None where the file has no colours, or not one per point.
    np.save(tmp_path / "cloud.npy", points)
    trimesh.PointCloud(points).export(tmp_path / "plain.ply")
    trimesh.creation.box().export(tmp_path / "plain.glb")
    assert read_point_colours(tmp_path / "cloud.npy", 50) is None
    assert read_point_colours(tmp_path / "plain.ply", 50) is None
    assert read_point_colours(tmp_path / "plain.glb", 8) is None
    assert read_point_colours(tmp_path / "cloud.ply", 49) is None
    np.savez(tmp_path / "bad.npz", points=points, colors=np.full((50, 3), 999.0))
    with pytest.raises(ValueError, match="bad.npz.*reach 999"):
        read_point_colours(tmp_path / "bad.npz", 50)


def test_a_depth_images_points_take_their_pixels_colours(tmp_path):
    import imageio.v3 as iio

    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]])
    camera = Camera(K=K, R=torch.eye(3), t=torch.zeros(3), width=32, height=24)
    depth = np.zeros((24, 32), np.uint16)
    depth[5:15, 8:20] = 400
    iio.imwrite(tmp_path / "depth.png", depth)
    colour = np.zeros((24, 32, 3), np.uint8)
    colour[..., 0] = np.arange(32)[None] * 8  # red along the columns, green along the rows
    colour[..., 1] = np.arange(24)[:, None] * 10
    iio.imwrite(tmp_path / "colour.png", colour)
    frame = DepthFrame(camera=camera, colour=tmp_path / "colour.png")
    points, _, _ = read_depth_cloud(tmp_path / "depth.png", frame)
    rows, columns = np.nonzero(depth > 0)
    expected = colour[rows, columns].astype(np.float32) / 255.0
    assert np.allclose(depth_point_colours(points, frame, frame.colour), expected, atol=1e-6)
    # A colour image at twice the size is scaled; another shape is refused.
    iio.imwrite(tmp_path / "big.png", np.repeat(np.repeat(colour, 2, 0), 2, 1))
    scaled = depth_point_colours(points, frame, tmp_path / "big.png")
    assert np.abs(scaled - expected).max() < 0.05
    iio.imwrite(tmp_path / "wide.png", np.zeros((24, 48, 3), np.uint8))
    with pytest.raises(ValueError, match="register it to the depth camera"):
        depth_point_colours(points, frame, tmp_path / "wide.png")


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_colour_code_is_fitted_to_the_scans_colours(side):
    """A colour model's hand coloured with a code it was not given: the fitted code gives the
    scan's colours back (against the start's error), on a left hand (mirrored) too."""
    import dataclasses

    from lisa_hand.fitting.points.colours import fit_colour_code
    from lisa_hand.inference.hand_field import hand_field
    from tests.fitting.test_points import surface, tiny_model, true_hand

    model = tiny_model(color=True)
    start = dataclasses.replace(true_hand(model, seed=1), side=side)
    start.color_code = model.mean_color_code()
    truth = dataclasses.replace(start, color_code=10 * torch.randn(
        8, generator=torch.Generator().manual_seed(3)))
    points = torch.as_tensor(surface(model, start).vertices[::3])
    if side == "left":
        points = points * torch.tensor([-1.0, 1.0, 1.0])  # the left hand's surface
    colours = hand_field(model, truth).attributes(points, skin_weights=False)[0]
    before = hand_field(model, start).attributes(points, skin_weights=False)[0]
    code = fit_colour_code(model, start, points.numpy(), colours.numpy(), iters=200,
                           code_weight=0.0)
    after = hand_field(model, dataclasses.replace(start, color_code=code)).attributes(
        points, skin_weights=False)[0]
    error_before = (before - colours).abs().mean()
    assert error_before > 0.015
    assert (after - colours).abs().mean() < 0.25 * error_before
    assert all(not p.requires_grad or p.grad is None for p in model.field.parameters())
    with pytest.raises(ValueError, match="no colour"):
        fit_colour_code(tiny_model(), start, points.numpy(), colours.numpy())
