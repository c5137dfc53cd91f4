"""Ground-truth rendering on a sphere, checked against closed-form ray-sphere intersections."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.data.images import project_keypoints, render_views, sphere_trace_views
from lisa_hand.data.shading import GainBias, GainBiasConfig, ShadingConfig
from lisa_hand.geometry import Camera, intrinsics_from_fov, look_at, project_points
from lisa_hand.render.raycast import MeshRayCaster

RADIUS = 0.1
WIDTH, HEIGHT = 64, 48


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64)


@pytest.fixture(scope="module")
def fine_sphere():
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64)


def axis_camera(distance: float = 0.5) -> Camera:
    """Camera at (0, 0, -distance) looking along +z at the origin, identity rotation."""
    return Camera(K=intrinsics_from_fov(40.0, WIDTH, HEIGHT), R=torch.eye(3),
                  t=torch.tensor([0.0, 0.0, distance]), width=WIDTH, height=HEIGHT, name="axis")


def oblique_camera() -> Camera:
    R, t = look_at(torch.tensor([0.25, 0.3, 0.35]), torch.tensor([0.01, -0.02, 0.0]))
    return Camera(K=intrinsics_from_fov(45.0, 40, 30), R=R, t=t, width=40, height=30)


def analytic_sphere(camera: Camera):
    """Closed-form first hits of every pixel-centre ray with the sphere (float64 numpy).

    -> hit [H, W] bool, points [H, W, 3], depth [H, W] (camera z), cos_incidence [H, W]
    """
    K = camera.K.double().numpy()
    R = camera.R.double().numpy()
    t = camera.t.double().numpy()
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    pixels = np.stack([u, v, np.ones_like(u)], -1)
    directions = pixels @ np.linalg.inv(K).T @ R  # rows: R^T K^-1 [u, v, 1]
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    origin = -R.T @ t
    half_b = directions @ origin
    disc = half_b**2 - (origin @ origin - RADIUS**2)
    hit = disc > 0
    s = -half_b - np.sqrt(np.clip(disc, 0, None))
    points = origin + s[..., None] * directions
    depth = (points - origin) @ R[2]
    cos_incidence = -(points / RADIUS * directions).sum(-1)
    return hit, points, depth, cos_incidence


def affine_albedo(points):
    """Albedo linear in position, in [0.3, 0.7] on the sphere (torch or numpy in and out)."""
    offset = torch.tensor([0.5, 0.45, 0.55], dtype=points.dtype)
    scale = torch.tensor([2.0, -1.5, 1.0], dtype=points.dtype)
    return offset + scale * points


def depth_error_along_normal(view, depth, cos_incidence, hit) -> float:
    """Max depth error times the incidence cosine (the facets' offset along the normal) on the
    pixels both hit, leaving out grazing rays (cosine < 0.2)."""
    both = view.mask & hit & (cos_incidence > 0.2)
    return float((np.abs(view.depth[both] - depth[both]) * cos_incidence[both]).max())


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_mask_depth_and_background_match_the_analytic_sphere(sphere):
    camera = axis_camera()
    shading = ShadingConfig(background=(0.2, 0.3, 0.4))
    (view,) = render_views(*sphere, [camera], affine_albedo, shading)
    hit, _, depth, cos_incidence = analytic_sphere(camera)
    assert view.rgb.shape == (HEIGHT, WIDTH, 3) and view.rgb.dtype == np.float32
    assert view.mask.shape == (HEIGHT, WIDTH) and view.mask.dtype == bool
    assert iou(view.mask, hit) > 0.98
    assert 800 < view.mask.sum() < 1200  # a disc of ~18 px radius
    # Depth: zero on the background, the closed form inside (the icosphere's facets sit less
    # than 0.1 mm inside the sphere; more along grazing rays).
    assert (view.depth[~view.mask] == 0).all()
    assert depth_error_along_normal(view, depth, cos_incidence, hit) < 1.2e-4
    # The four pixels around the image centre see the sphere's pole at 0.5 - 0.1 = 0.4 m.
    centre = view.depth[HEIGHT // 2 - 1:HEIGHT // 2 + 1, WIDTH // 2 - 1:WIDTH // 2 + 1]
    np.testing.assert_allclose(centre, 0.4, atol=2e-4)
    np.testing.assert_array_equal(view.rgb[~view.mask], np.broadcast_to(
        np.float32([0.2, 0.3, 0.4]), (int((~view.mask).sum()), 3)))
    np.testing.assert_array_equal(view.gain, np.ones(3))
    np.testing.assert_array_equal(view.bias, np.zeros(3))


def test_lambert_shading_at_a_hand_computed_pixel(sphere):
    camera = axis_camera()
    shading = ShadingConfig(ambient=0.25, diffuse=0.75, light_directions=((0.3, -0.5, -1.0),))
    (view,) = render_views(*sphere, [camera], affine_albedo, shading, return_normals=True)
    # Pixel (u, v) = (40, 20): ray through (40.5, 20.5), by hand.
    focal = 32.0 / math.tan(math.radians(20.0))
    direction = np.array([(40.5 - 32.0) / focal, (20.5 - 24.0) / focal, 1.0])
    direction /= np.linalg.norm(direction)
    origin = np.array([0.0, 0.0, -0.5])
    half_b = direction @ origin
    s = -half_b - math.sqrt(half_b**2 - (origin @ origin - RADIUS**2))
    point = origin + s * direction
    normal = point / RADIUS
    light = np.array([0.3, -0.5, -1.0]) / np.linalg.norm([0.3, -0.5, -1.0])
    albedo = np.array([0.5, 0.45, 0.55]) + np.array([2.0, -1.5, 1.0]) * point
    expected = albedo * (0.25 + 0.75 * max(0.0, normal @ light))
    assert view.mask[20, 40]
    np.testing.assert_allclose(view.rgb[20, 40], expected, atol=3e-3)
    np.testing.assert_allclose(view.normals[20, 40], normal, atol=3e-3)
    np.testing.assert_allclose(view.depth[20, 40], point[2] + 0.5, atol=2e-4)
    np.testing.assert_allclose(view.light_directions, light[None], atol=1e-6)
    # Shading over the whole disc, against the closed form.
    hit, points, _, _ = analytic_sphere(camera)
    both = view.mask & hit
    normals = points / RADIUS
    albedo = np.array([0.5, 0.45, 0.55]) + np.array([2.0, -1.5, 1.0]) * points
    expected = albedo * (0.25 + 0.75 * np.clip(normals @ light, 0, None))[..., None]
    assert np.abs(view.rgb[both] - expected[both]).max() < 0.01
    np.testing.assert_allclose(np.linalg.norm(view.normals[view.mask], axis=-1), 1.0, atol=1e-5)
    assert (view.normals[~view.mask] == 0).all()


def test_oblique_camera_and_camera_frame_light(sphere):
    camera = oblique_camera()
    shading = ShadingConfig(ambient=0.3, diffuse=0.7, light_directions=((0.0, 0.0, -1.0),))
    (view,) = render_views(*sphere, [camera], (0.6, 0.5, 0.4), shading)
    hit, points, depth, cos_incidence = analytic_sphere(camera)
    assert iou(view.mask, hit) > 0.98
    both = view.mask & hit & (cos_incidence > 0.2)
    assert depth_error_along_normal(view, depth, cos_incidence, hit) < 1.2e-4
    # A headlight: the light direction is minus the camera's z axis, n . l = -n . z.
    light_world = -camera.R[2].double().numpy()
    np.testing.assert_allclose(view.light_directions[0], light_world, atol=1e-6)
    cos = np.clip((points / RADIUS) @ light_world, 0, None)
    expected = np.array([0.6, 0.5, 0.4]) * (0.3 + 0.7 * cos)[..., None]
    assert np.abs(view.rgb[both] - expected[both]).max() < 0.01


def test_gain_and_bias(sphere):
    cameras = [axis_camera(), oblique_camera()]
    plain = render_views(*sphere, cameras, affine_albedo)
    gain = np.array([[1.1, 0.9, 1.0], [0.8, 1.2, 1.05]])
    bias = np.array([[0.02, -0.03, 0.0], [-0.05, 0.04, 0.01]])
    shaded = render_views(*sphere, cameras, affine_albedo, gain_bias=GainBias(gain, bias))
    for index, (a, b) in enumerate(zip(plain, shaded, strict=True)):
        np.testing.assert_array_equal(a.mask, b.mask)
        expected = np.clip(gain[index] * a.rgb[a.mask] + bias[index], 0, 1)
        np.testing.assert_allclose(b.rgb[b.mask], expected, atol=1e-6)
        np.testing.assert_array_equal(b.rgb[~b.mask], 0.0)  # the background is not calibrated
        np.testing.assert_allclose(b.gain, gain[index], atol=1e-7)
        np.testing.assert_allclose(b.bias, bias[index], atol=1e-7)
    # Sampled per camera and channel, inside the ranges, reproducible from the seed.
    config = GainBiasConfig(gain_range=(0.85, 1.15), bias_range=(-0.05, 0.05))
    first = render_views(*sphere, cameras, affine_albedo, generator=3, gain_bias=config)
    again = render_views(*sphere, cameras, affine_albedo, generator=3, gain_bias=config)
    gains = np.stack([v.gain for v in first])
    biases = np.stack([v.bias for v in first])
    assert ((gains >= 0.85) & (gains <= 1.15)).all()
    assert ((biases >= -0.05) & (biases <= 0.05)).all()
    assert len(np.unique(gains)) == 6 and len(np.unique(biases)) == 6
    for a, b, p in zip(first, again, plain, strict=True):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_allclose(a.rgb[a.mask], np.clip(a.gain * p.rgb[p.mask] + a.bias, 0, 1),
                                   atol=1e-6)
    with pytest.raises(ValueError, match="generator"):
        render_views(*sphere, cameras, affine_albedo, gain_bias=config)


def test_random_lights(sphere):
    cameras = [axis_camera(), oblique_camera()]
    nominal = np.array([0.0, -0.5, -1.0]) / np.linalg.norm([0.0, -0.5, -1.0])
    shading = ShadingConfig(random_light=True, light_jitter_deg=20.0)
    views = render_views(*sphere, cameras, affine_albedo, shading, generator=7)
    again = render_views(*sphere, cameras, affine_albedo, shading, generator=7)
    for view, repeat, camera in zip(views, again, cameras, strict=True):
        np.testing.assert_array_equal(view.light_directions, repeat.light_directions)
        light_cam = camera.R.double().numpy() @ view.light_directions[0]
        angle = math.degrees(math.acos(np.clip(light_cam @ nominal, -1, 1)))
        assert 0.0 < angle <= 20.0 + 1e-3
    world = ShadingConfig(light_frame="world", light_directions=((1.0, 1.0, 0.0),),
                          random_light=True, light_jitter_deg=10.0)
    views = render_views(*sphere, cameras, affine_albedo, world, generator=1)
    np.testing.assert_array_equal(views[0].light_directions, views[1].light_directions)
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    assert math.degrees(math.acos(views[0].light_directions[0] @ axis)) <= 10.0 + 1e-3


def test_albedo_inputs_agree(sphere):
    """A callback at the hit, per-vertex colours and rest-pose lookups give the same image for an
    affine albedo (barycentric interpolation of an affine function is exact)."""
    vertices, faces = sphere
    camera = oblique_camera()
    shift = np.array([0.01, -0.02, 0.03], np.float32)
    (reference,) = render_views(vertices, faces, [camera],
                                lambda p: affine_albedo(p + torch.from_numpy(shift)))
    (rest,) = render_views(vertices, faces, [camera], affine_albedo,
                           albedo_vertices=vertices + shift)
    colours = affine_albedo(torch.from_numpy(vertices + shift)).numpy()
    (per_vertex,) = render_views(vertices, faces, [camera], colours)
    np.testing.assert_allclose(rest.rgb, reference.rgb, atol=1e-5)
    np.testing.assert_allclose(per_vertex.rgb, reference.rgb, atol=1e-5)
    # A reused caster and torch inputs give the same result.
    caster = MeshRayCaster(torch.from_numpy(vertices), torch.from_numpy(faces))
    (reused,) = render_views(None, None, [camera], colours, caster=caster)
    np.testing.assert_array_equal(reused.rgb, per_vertex.rgb)


def test_supersampling(sphere):
    camera = axis_camera()
    (sharp,) = render_views(*sphere, [camera], affine_albedo)
    (smooth,) = render_views(*sphere, [camera], affine_albedo, supersample=3)
    hit, _, depth, cos_incidence = analytic_sphere(camera)
    assert iou(smooth.mask, hit) > 0.98
    # Away from the silhouette the sub-pixel average equals the centre sample to first order.
    interior = sharp.mask & smooth.mask
    for _ in range(2):
        interior[1:-1, 1:-1] &= (interior[:-2, 1:-1] & interior[2:, 1:-1]
                                 & interior[1:-1, :-2] & interior[1:-1, 2:])
    assert np.abs(smooth.rgb[interior] - sharp.rgb[interior]).max() < 0.01
    assert np.abs(smooth.depth[interior] - depth[interior]).max() < 5e-4
    assert depth_error_along_normal(sharp, depth, cos_incidence, hit) < 1.2e-4
    # Edge pixels blend the surface with the black background.
    edge = sharp.mask & ~interior
    assert (smooth.rgb[edge].sum(-1) < sharp.rgb[edge].sum(-1) + 1e-6).mean() > 0.9


def test_camera_inside_the_mesh_sees_back_faces_everywhere():
    """No bounding-rectangle culling when the camera is inside the box; back faces get normals
    flipped towards the camera."""
    room = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    camera = axis_camera(0.5)  # at (0, 0, -0.5), inside the unit sphere
    (view,) = render_views(room.vertices, room.faces, [camera], (0.5, 0.5, 0.5),
                           ShadingConfig(ambient=0.0, diffuse=1.0,
                                         light_directions=((0.0, 0.0, -1.0),)),
                           return_normals=True)
    assert view.mask.all()
    # Straight ahead the wall is at z = 1: depth 1.5 m; it faces the camera (normal -z).
    centre = view.depth[HEIGHT // 2 - 1:HEIGHT // 2 + 1, WIDTH // 2 - 1:WIDTH // 2 + 1]
    np.testing.assert_allclose(centre, 1.5, atol=0.01)
    assert (view.normals[..., 2] < 0).all() and (view.rgb > 0.3).all()


def test_views_of_different_sizes(sphere):
    cameras = [axis_camera(), oblique_camera()]
    views = render_views(*sphere, cameras, affine_albedo)
    assert views[0].rgb.shape == (48, 64, 3) and views[1].rgb.shape == (30, 40, 3)
    assert views[1].depth.shape == (30, 40) and views[1].mask.sum() > 50


def test_sphere_tracing_agrees_with_ray_casting(fine_sphere):
    cameras = [axis_camera(), oblique_camera()]

    def sdf_fn(points):
        return points.norm(dim=-1) - RADIUS

    cast = render_views(*fine_sphere, cameras, affine_albedo, return_normals=True)
    traced = sphere_trace_views(sdf_fn, cameras, affine_albedo, (0.0, 0.0, 0.0), 0.12,
                                return_normals=True)
    for a, b, camera in zip(cast, traced, cameras, strict=True):
        hit, _, depth, cos_incidence = analytic_sphere(camera)
        assert iou(a.mask, b.mask) > 0.98 and iou(b.mask, hit) > 0.98
        both = a.mask & b.mask & (cos_incidence > 0.2)
        assert np.abs(a.depth[both] - b.depth[both]).max() < 5e-4
        assert depth_error_along_normal(b, depth, cos_incidence, hit) < 1e-4
        assert np.abs(a.rgb[both] - b.rgb[both]).max() < 0.01
        assert np.abs(a.normals[both] - b.normals[both]).max() < 0.01


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_sphere_tracing_on_cuda_matches_cpu():
    cameras = [axis_camera()]

    def sdf_fn(points):
        return points.norm(dim=-1) - RADIUS

    (cpu,) = sphere_trace_views(sdf_fn, cameras, affine_albedo, (0.0, 0.0, 0.0), 0.12)
    cuda_cameras = [camera.to("cuda") for camera in cameras]
    (gpu,) = sphere_trace_views(sdf_fn, cuda_cameras,
                                lambda p: affine_albedo(p.cpu()).to(p.device), (0.0, 0.0, 0.0),
                                0.12)
    assert iou(cpu.mask, gpu.mask) > 0.99
    both = cpu.mask & gpu.mask
    assert np.abs(cpu.depth[both] - gpu.depth[both]).max() < 1e-4


def test_project_keypoints():
    camera = oblique_camera()
    generator = torch.Generator().manual_seed(0)
    keypoints = 0.15 * torch.randn(21, 3, generator=generator, dtype=torch.float64)
    result = project_keypoints(keypoints, camera)
    pixels, depth = project_points(camera.K.double(), camera.R.double(), camera.t.double(),
                                   keypoints)
    np.testing.assert_allclose(result.pixels, pixels.numpy(), rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(result.depth, depth.numpy(), rtol=1e-6)
    u, v = pixels[:, 0].numpy(), pixels[:, 1].numpy()
    inside = (depth.numpy() > 0) & (u >= 0) & (u < 40) & (v >= 0) & (v < 30)
    np.testing.assert_array_equal(result.in_image, inside)
    np.testing.assert_array_equal(result.visible, inside)
    assert 0 < inside.sum() < 21  # the test exercises both cases


def test_keypoint_occlusion_by_depth(sphere):
    camera = axis_camera()
    (view,) = render_views(*sphere, [camera], affine_albedo)
    keypoints = np.array([
        [0.0, 0.0, -0.2],  # in front of the sphere: visible
        [0.0, 0.0, -0.09],  # 1 cm under the surface, within the tolerance: visible
        [0.0, 0.0, 0.0],  # the centre, 10 cm behind the surface: occluded
        [0.0, 0.0, 0.3],  # behind the sphere: occluded
        [0.3, 0.0, 0.0],  # outside the image
        [0.0, 0.05, 0.05],  # behind the sphere's upper part
    ])
    result = project_keypoints(keypoints, camera, depth=view.depth)
    np.testing.assert_array_equal(result.in_image, [True, True, True, True, False, True])
    np.testing.assert_array_equal(result.visible, [True, True, False, False, False, False])
    with pytest.raises(ValueError, match="depth"):
        project_keypoints(keypoints, camera, depth=view.depth[:10])


def test_invalid_inputs(sphere):
    vertices, faces = sphere
    camera = axis_camera()
    with pytest.raises(ValueError, match="vertices"):
        render_views(vertices[:, :2], faces, [camera], affine_albedo)
    with pytest.raises(ValueError, match="faces"):
        render_views(vertices, faces + len(vertices), [camera], affine_albedo)
    with pytest.raises(TypeError, match="cameras"):
        render_views(vertices, faces, ["camera"], affine_albedo)
    with pytest.raises(ValueError, match="albedo_fn"):
        render_views(vertices, faces, [camera], lambda p: 2.0 + p)
    with pytest.raises(ValueError, match="albedo_fn"):
        render_views(vertices, faces, [camera], np.zeros((5, 3)))
    with pytest.raises(ValueError, match="supersample"):
        render_views(vertices, faces, [camera], affine_albedo, supersample=0)
    with pytest.raises(ValueError, match="light_frame"):
        ShadingConfig(light_frame="object")
    with pytest.raises(ValueError, match="background"):
        ShadingConfig(background=(0.0, 2.0, 0.0))
    with pytest.raises(ValueError, match="gain"):
        render_views(vertices, faces, [camera, camera], affine_albedo,
                     gain_bias=GainBias(np.ones((3, 3)), np.zeros((3, 3))))
