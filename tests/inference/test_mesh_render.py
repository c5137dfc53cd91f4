"""The mesh render (lisa_hand.inference.mesh_render): the silhouette of a sphere against its
closed form, the model's shading against the generator's own renderer (an independent
implementation of the same Lambert term), colours over black, and the mesh of a hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand import inference
from lisa_hand.data.images import render_views
from lisa_hand.data.shading import ShadingConfig
from lisa_hand.geometry.cameras import Camera
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.inference.mesh_render import render_mesh
from lisa_hand.render.shading import HeadlightShading

from .helpers import hand_params

FOCAL, SIZE = 300.0, 96
COLOUR = np.array([200, 120, 90], np.uint8)


def camera(rotation=None) -> Camera:
    rotation = torch.eye(3) if rotation is None else rotation
    K = torch.tensor([[FOCAL, 0.0, SIZE / 2], [0.0, FOCAL, SIZE / 2], [0.0, 0.0, 1.0]])
    return Camera(K=K, R=rotation, t=torch.zeros(3), width=SIZE, height=SIZE, name="c")


def ball(radius: float, centre) -> Mesh:
    """A sphere of one colour, in front of the camera."""
    sphere = trimesh.creation.icosphere(5, radius)
    sphere.apply_translation(centre)
    return Mesh(vertices=sphere.vertices, faces=sphere.faces,
                colors=np.broadcast_to(COLOUR, sphere.vertices.shape).copy())


def test_silhouette_of_a_sphere_and_its_unlit_colour(model):
    radius, depth = 0.03, 0.4
    unlit = dataclasses.replace(model, shading=None)
    image = render_mesh(unlit, ball(radius, (0.0, 0.0, depth)), camera(), supersample=4)
    # The silhouette of a sphere on the optical axis: a disc of radius f r / sqrt(d^2 - r^2).
    disc = math.pi * (FOCAL * radius / math.sqrt(depth**2 - radius**2)) ** 2
    assert float(image.alpha.sum()) == pytest.approx(disc, rel=0.01)
    inside = image.alpha == 1.0
    assert inside.sum() > 0.7 * disc
    np.testing.assert_allclose(image.rgb[inside], np.broadcast_to(COLOUR / 255.0, (
        int(inside.sum()), 3)), atol=1e-6)
    # Colours over black: an edge pixel holds the colour times its coverage.
    edge = (image.alpha > 0.0) & (image.alpha < 1.0)
    assert edge.sum() > 0
    np.testing.assert_allclose(image.rgb[edge], image.alpha[edge, None] * COLOUR / 255.0,
                               atol=1e-6)
    assert image.rgb[image.alpha == 0.0].max() == 0.0


@pytest.mark.parametrize("learned", [False, True])
def test_shading_is_the_generators_lambert_term(model, learned):
    angle = 0.4  # a camera turned about y: the light follows it
    rotation = torch.tensor([[math.cos(angle), 0.0, -math.sin(angle)], [0.0, 1.0, 0.0],
                             [math.sin(angle), 0.0, math.cos(angle)]])
    view = camera(rotation)
    light = (0.3, -0.5, -0.8)
    shading = HeadlightShading(0.65, learn_light=learned, light=light)
    lit = dataclasses.replace(model, shading=shading)
    centre = (rotation.T @ torch.tensor([0.01, 0.005, 0.4])).numpy()  # in front of the camera
    mesh = ball(0.03, centre)
    image = render_mesh(lit, mesh, view, supersample=1)
    if learned:
        # The generator's renderer: ambient + diffuse max(0, n . l), l fixed in the camera frame.
        config = ShadingConfig(ambient=0.35, diffuse=0.65, light_directions=(light,),
                               light_frame="camera")
        (truth,) = render_views(mesh.vertices, mesh.faces, [view], COLOUR / 255.0, config)
        expected = truth.rgb
    else:
        # The headlight: the light at the camera centre, n . -d with d each pixel's ray (numpy).
        (truth,) = render_views(mesh.vertices, mesh.faces, [view], COLOUR / 255.0,
                                ShadingConfig(ambient=1.0, diffuse=0.0), return_normals=True)
        u, v = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)
        pixels = np.stack([u, v, np.ones_like(u)], axis=-1)
        rays = pixels @ np.linalg.inv(view.K.double().numpy()).T @ rotation.double().numpy()
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        cosine = np.clip(-(truth.normals * rays).sum(-1, keepdims=True), 0.0, None)
        expected = truth.rgb * (0.35 + 0.65 * cosine)
    assert np.array_equal(truth.mask, image.alpha == 1.0)
    np.testing.assert_allclose(image.rgb[truth.mask], expected[truth.mask], atol=1e-5)


def test_a_hand_mesh_and_bad_inputs(model, right_mesh):
    params = hand_params(model)
    mesh = right_mesh.mesh
    K = torch.tensor([[500.0, 0.0, 64.0], [0.0, 500.0, 64.0], [0.0, 0.0, 1.0]])
    # Look at the hand from its translation's direction: the camera at the origin.
    view = Camera(K=K, R=torch.eye(3), t=torch.zeros(3), width=128, height=128, name="c")
    image = render_mesh(model, mesh, view)
    assert image.rgb.shape == (128, 128, 3) and image.alpha.shape == (128, 128)
    assert 0.05 < float((image.alpha > 0.5).mean()) < 0.95
    assert params.translation[2] > 0
    empty = Mesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), np.int64))
    blank = render_mesh(model, empty, view)
    assert blank.alpha.max() == 0.0 and blank.rgb.max() == 0.0
    with pytest.raises(ValueError, match="supersample"):
        render_mesh(model, mesh, view, supersample=0)


def test_mesh_attributes_and_mirror_mesh(model, right_mesh):
    params = hand_params(model)
    mesh = right_mesh.mesh
    bare = Mesh(vertices=mesh.vertices, faces=mesh.faces)
    again = inference.mesh_attributes(model, params, bare)
    np.testing.assert_array_equal(again.colors, mesh.colors)
    np.testing.assert_allclose(again.skin_weights, mesh.skin_weights, atol=1e-6)
    only = inference.mesh_attributes(model, params, bare, inference.MeshConfig(colors=False,
                                                                               skin_weights=False))
    assert only.colors is None and only.skin_weights is None
    mirrored = inference.mirror_mesh(mesh)
    np.testing.assert_array_equal(mirrored.vertices[:, 0], -mesh.vertices[:, 0])
    np.testing.assert_array_equal(mirrored.vertices[:, 1:], mesh.vertices[:, 1:])

    def volume(one: Mesh) -> float:  # positive for outward faces
        return float(trimesh.Trimesh(one.vertices, one.faces, process=False).volume)

    assert volume(mesh) > 0 and volume(mirrored) == pytest.approx(volume(mesh), rel=1e-5)
    np.testing.assert_array_equal(mirrored.colors, mesh.colors)


def test_a_mesh_without_colours_is_grey_and_lit_from_the_camera(model):
    # A mesh without colours, or any mesh of a geometry-only model: grey 0.8 times ambient 0.3
    # + diffuse 0.7 max(0, n . l), whatever the model's own shading; brightest where the
    # sphere faces the light.
    sphere = ball(0.03, (0.0, 0.0, 0.4))
    grey = Mesh(vertices=sphere.vertices, faces=sphere.faces)
    geometry_only = dataclasses.replace(model, color_codes=None)  # its mesh: grey colours
    cases = [(dataclasses.replace(model, shading=None), grey),
             (dataclasses.replace(model, shading=HeadlightShading(0.65)), grey),
             (geometry_only, sphere)]
    for owner, mesh in cases:
        image = render_mesh(owner, mesh, camera(), supersample=1)
        inside = image.alpha == 1.0
        values = image.rgb[inside]
        np.testing.assert_allclose(values[:, 0], values[:, 2])  # grey
        assert values.max() == pytest.approx(0.8, abs=0.01)
        assert values.min() >= 0.8 * 0.3 - 1e-6 and values.max() - values.min() > 0.2
