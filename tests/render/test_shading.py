"""Headlight shading (:mod:`lisa_hand.render.shading`): normals at the rays' surface points of an
analytic sphere against the closed form, the Lambert factor and its gradients, the shading of
composited and calibrated colours, and the parameters' round trip."""

from __future__ import annotations

import math

import pytest
import torch

from lisa_hand.render.shading import HeadlightShading, shade_foreground, surface_normals

CENTRE = torch.tensor([0.01, -0.02, 0.5], dtype=torch.float64)
RADIUS = 0.05


def _sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    return (points - CENTRE).norm(dim=-1) - RADIUS


def _rays(num: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    origins = torch.zeros(num, 3, dtype=torch.float64)
    aim = CENTRE + 0.08 * (torch.rand(num, 3, generator=generator, dtype=torch.float64) - 0.5)
    return origins, torch.nn.functional.normalize(aim - origins, dim=-1)


def _sphere_hits(origins, directions):
    """Closed-form first hit distance of each ray with the sphere and whether it hits."""
    offset = origins - CENTRE
    half_b = (offset * directions).sum(-1)
    disc = half_b**2 - ((offset * offset).sum(-1) - RADIUS**2)
    return -half_b - disc.clamp_min(0).sqrt(), disc > 0


def test_surface_normals_of_a_sphere_are_the_radial_directions():
    origins, directions = _rays(300)
    depth, hit = _sphere_hits(origins, directions)
    opacity = hit.double()
    normals = surface_normals(_sphere_sdf, origins, directions, depth, opacity)
    points = origins + depth[:, None] * directions
    expected = (points - CENTRE) / RADIUS
    assert 50 < int(hit.sum()) < 300
    torch.testing.assert_close(normals[hit], expected[hit], rtol=0, atol=1e-9)
    assert torch.equal(normals[~hit], torch.zeros_like(normals[~hit]))  # no surface: skipped


def test_grouped_surface_normals_use_each_rays_group():
    origins, directions = _rays(64, seed=1)
    depth, hit = _sphere_hits(origins, directions)
    groups = torch.arange(64) % 2
    shifts = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.003]], dtype=torch.float64)

    def grouped(points, point_groups):  # group 1: the sphere moved 3 mm along z
        return _sphere_sdf(points - shifts[point_groups])

    normals = surface_normals(grouped, origins, directions, depth, hit.double(), groups)
    points = origins + depth[:, None] * directions
    expected = torch.nn.functional.normalize(points - CENTRE - shifts[groups], dim=-1)
    torch.testing.assert_close(normals[hit], expected[hit], rtol=0, atol=1e-9)


def test_lambert_factor_closed_form_and_gradients():
    shading = HeadlightShading.from_values(0.7).double()
    assert float(shading.diffuse.detach()) == pytest.approx(0.7)
    angle = torch.tensor([0.0, math.pi / 3, math.pi / 2, 2.0], dtype=torch.float64)
    directions = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand(4, 3)
    normals = torch.stack([torch.sin(angle), torch.zeros(4, dtype=torch.float64),
                           -torch.cos(angle)], dim=-1)  # angle from the ray's reverse
    albedo = torch.tensor([0.8, 0.5, 0.3], dtype=torch.float64).expand(4, 3)
    shaded = shading(albedo, normals, directions)
    cosine = torch.cos(angle).clamp_min(0)[:, None]
    torch.testing.assert_close(shaded, albedo * (0.3 + 0.7 * cosine))
    torch.testing.assert_close(shaded[0], albedo[0])  # facing the camera: the albedo
    torch.testing.assert_close(shaded[2:], 0.3 * albedo[2:])  # edge-on, facing away: ambient
    shaded.sum().backward()
    slope = 0.7 * 0.3  # d sigmoid / d raw at k = 0.7
    expected = slope * float((albedo * (cosine - 1.0)).sum())
    assert float(shading.diffuse_raw.grad) == pytest.approx(expected, rel=1e-6)


def test_shade_foreground_leaves_the_background_and_the_bias():
    generator = torch.Generator().manual_seed(3)
    albedo = torch.rand(50, 3, generator=generator)
    opacity = torch.rand(50, generator=generator)
    gain, bias = torch.tensor([1.1, 0.9, 1.0]), torch.tensor([0.05, -0.02, 0.01])
    background = torch.tensor([0.2, 0.3, 0.4])
    factor = torch.rand(50, 3, generator=generator) + 0.2
    alpha = opacity[:, None]
    composited = gain * albedo * alpha + bias * alpha + (1 - alpha) * background
    expected = gain * albedo * alpha * factor + bias * alpha + (1 - alpha) * background
    shaded = shade_foreground(composited, opacity, background, factor, bias)
    torch.testing.assert_close(shaded, expected)


def test_values_round_trip_and_bad_values():
    shading = HeadlightShading()
    assert float(shading.diffuse.detach()) == pytest.approx(0.5)
    again = HeadlightShading.from_values(**HeadlightShading.from_values(0.62).values())
    assert float(again.diffuse) == pytest.approx(0.62)
    for bad in (0.0, 1.0, float("nan"), torch.ones(2)):
        with pytest.raises(ValueError, match="diffuse"):
            HeadlightShading.from_values(bad)


def _random_rotations(num: int, generator: torch.Generator) -> torch.Tensor:
    """[num, 3, 3] float64 proper rotations (QR of Gaussian matrices, signs fixed)."""
    q, r = torch.linalg.qr(torch.randn(num, 3, 3, generator=generator, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1))[:, None, :]
    return q * torch.det(q)[:, None, None]


def test_camera_light_matches_the_generators_shading():
    """A learned camera light set to the generator's light gives the generator's shading
    (:func:`lisa_hand.data.shading.shade`, an independent implementation): each camera's light
    turned into the world frame, ambient 1 - k, diffuse k, one light."""
    import numpy as np

    from lisa_hand.data.shading import ShadingConfig, lights_per_view, shade
    from lisa_hand.geometry.cameras import Camera

    generator = torch.Generator().manual_seed(5)
    light = (0.0, -0.5, -1.0)
    shading = HeadlightShading(0.65, learn_light=True, light=light).double()
    config = ShadingConfig(ambient=0.35, diffuse=0.65, light_directions=(light,))
    rotations = _random_rotations(4, generator)
    cameras = [Camera(K=torch.eye(3), R=rotation.float(), t=torch.zeros(3), width=8, height=8)
               for rotation in rotations]
    world_lights = lights_per_view(cameras, config, None)
    normals = torch.nn.functional.normalize(
        torch.randn(4, 200, 3, generator=generator, dtype=torch.float64), dim=-1)
    albedo = torch.rand(4, 200, 3, generator=generator, dtype=torch.float64) * 0.9
    directions = torch.nn.functional.normalize(torch.randn(4, 200, 3, dtype=torch.float64), dim=-1)
    shaded = shading(albedo.reshape(-1, 3), normals.reshape(-1, 3), directions.reshape(-1, 3),
                     rotations[:, None].expand(4, 200, 3, 3).reshape(-1, 3, 3)).reshape(4, 200, 3)
    for view in range(4):
        expected = shade(normals[view].numpy(), albedo[view].numpy(), world_lights[view],
                         np.ones(3), np.zeros(3), config)
        np.testing.assert_allclose(shaded[view].detach().numpy(), expected, atol=2e-6)
    # The ray direction does not matter for a learned light; one [3, 3] rotation broadcasts.
    one = shading.factor(normals[0], -directions[0], rotations[0])
    torch.testing.assert_close(one, shading.factor(normals[0], directions[0],
                                                   rotations[0].expand(200, 3, 3)))


def test_camera_light_gradient_and_start():
    """The light direction gets the finite-difference gradient; it starts on the camera axis,
    where a surface facing the camera keeps its albedo; without rotations it refuses."""
    generator = torch.Generator().manual_seed(6)
    shading = HeadlightShading(0.6, learn_light=True).double()
    assert shading.learns_light and not HeadlightShading().learns_light
    torch.testing.assert_close(shading.light.detach(),
                               torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    rotation = _random_rotations(1, generator)[0]
    facing = -rotation[2]  # the world normal facing the camera: -(optical axis)
    factor = shading.factor(facing[None], torch.zeros(1, 3, dtype=torch.float64), rotation)
    torch.testing.assert_close(factor, torch.ones(1, 1, dtype=torch.float64))
    with torch.no_grad():
        shading.light_raw.copy_(torch.tensor([0.3, -0.4, -1.0], dtype=torch.float64))
    normals = torch.nn.functional.normalize(
        torch.randn(50, 3, generator=generator, dtype=torch.float64), dim=-1)
    directions = torch.zeros(50, 3, dtype=torch.float64)

    def energy():
        return (shading.factor(normals, directions, rotation) ** 2).sum()

    energy().backward()
    analytic = shading.light_raw.grad.clone()
    numeric = torch.zeros(3, dtype=torch.float64)
    for axis in range(3):
        with torch.no_grad():
            shading.light_raw[axis] += 1e-6
            plus = float(energy())
            shading.light_raw[axis] -= 2e-6
            minus = float(energy())
            shading.light_raw[axis] += 1e-6
        numeric[axis] = (plus - minus) / 2e-6
    torch.testing.assert_close(analytic, numeric, rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="rotations"):
        shading.factor(normals, directions)


def test_camera_light_values_round_trip():
    shading = HeadlightShading(0.4, learn_light=True, light=(0.0, -2.0, -4.0))
    values = shading.values()
    assert set(values) == {"diffuse", "light"}
    torch.testing.assert_close(values["light"], torch.tensor([0.0, -1.0, -2.0]) / math.sqrt(5))
    again = HeadlightShading.from_values(**values)
    assert again.learns_light
    torch.testing.assert_close(again.light.detach(), values["light"])
    assert float(again.diffuse.detach()) == pytest.approx(0.4)
    assert set(HeadlightShading().values()) == {"diffuse"}
    assert HeadlightShading.for_mode("none") is None
    assert HeadlightShading.for_mode("camera_light").learns_light
    for bad in ((0.0, 0.0, 0.0), (1.0, float("nan"), 0.0), (1.0, 2.0)):
        with pytest.raises(ValueError, match="light"):
            HeadlightShading(learn_light=True, light=bad)
    with pytest.raises(ValueError, match="shading"):
        HeadlightShading.for_mode("studio")
