"""Ray bounds: spheres (hand-computed and random rays) and boxes (against dense sampling)."""

import math

import pytest
import torch

from lisa_hand.geometry.rays import ray_box_bounds, ray_sphere_bounds


def test_ray_sphere_bounds_hand_computed():
    origins = torch.tensor(
        [
            [0.0, 0.0, -2.0],  # through the centre: near 1, far 3
            [0.0, 2.0, -2.0],  # misses (passes at distance 2)
            [0.0, 0.0, 0.5],  # inside: near 0, far 0.5
            [0.0, 0.0, 2.0],  # sphere entirely behind the origin
            [0.0, 0.6, -2.0],  # off-centre chord: t = 2 -+ 0.8
            [0.0, 0.0, -2.0],  # non-unit direction: t in units of |d| = 2
        ],
        dtype=torch.float64,
    )
    directions = torch.tensor([[0.0, 0.0, 1.0]] * 5 + [[0.0, 0.0, 2.0]], dtype=torch.float64)
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 1.0)
    assert hit.tolist() == [True, False, True, False, True, True]
    expected_near = [1.0, 0.0, 0.0, 0.0, 1.2, 0.5]
    expected_far = [3.0, 0.0, 0.5, 0.0, 2.8, 1.5]
    assert near.tolist() == pytest.approx(expected_near, abs=1e-12)
    assert far.tolist() == pytest.approx(expected_far, abs=1e-12)
    assert near.dtype == torch.float64


def test_ray_sphere_bounds_per_ray_centre_and_radius():
    origins = torch.zeros(2, 3)
    directions = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    centers = torch.tensor([[5.0, 0.0, 0.0], [0.0, 10.0, 0.0]])
    radius = torch.tensor([1.0, 2.0])
    near, far, hit = ray_sphere_bounds(origins, directions, centers, radius)
    assert hit.all()
    assert near.tolist() == pytest.approx([4.0, 8.0])
    assert far.tolist() == pytest.approx([6.0, 12.0])
    # The endpoints lie on the sphere.
    for t in (near, far):
        points = origins + t[:, None] * directions
        assert (points - centers).norm(dim=-1).tolist() == pytest.approx([1.0, 2.0], abs=1e-6)


def test_ray_sphere_bounds_random_rays_match_geometry():
    gen = torch.Generator().manual_seed(0)
    origins = torch.randn(200, 3, generator=gen, dtype=torch.float64)
    directions = torch.randn(200, 3, generator=gen, dtype=torch.float64)
    directions = directions / directions.norm(dim=-1, keepdim=True)
    center = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    near, far, hit = ray_sphere_bounds(origins, directions, center, 0.8)
    # Distance of the line to the centre, and whether the closest point is reachable.
    offset = center - origins
    t_closest = (offset * directions).sum(-1)
    dist = (offset - t_closest[:, None] * directions).norm(dim=-1)
    inside = offset.norm(dim=-1) < 0.8
    expected_hit = (dist < 0.8) & (inside | (t_closest > 0))
    assert torch.equal(hit, expected_hit)
    half = torch.sqrt(torch.clamp(0.8**2 - dist**2, min=0.0))
    torch.testing.assert_close(far[hit], (t_closest + half)[hit])
    torch.testing.assert_close(near[hit], torch.clamp(t_closest - half, min=0.0)[hit])
    assert math.isclose(float(near[~hit].abs().sum() + far[~hit].abs().sum()), 0.0)


def test_ray_sphere_bounds_validation():
    with pytest.raises(ValueError, match="origins"):
        ray_sphere_bounds(torch.zeros(3), torch.zeros(3), torch.zeros(3), 1.0)
    with pytest.raises(ValueError, match="directions"):
        ray_sphere_bounds(torch.zeros(2, 3), torch.zeros(3, 3), torch.zeros(3), 1.0)
    with pytest.raises(ValueError, match="center"):
        ray_sphere_bounds(torch.zeros(2, 3), torch.ones(2, 3), torch.zeros(2), 1.0)


def test_ray_box_bounds_match_sampling():
    generator = torch.Generator().manual_seed(1)
    origins = torch.randn(500, 3, generator=generator, dtype=torch.float64)
    directions = torch.randn(500, 3, generator=generator, dtype=torch.float64)
    directions[:50, 1] = 0.0  # axis-parallel rays
    directions = directions / directions.norm(dim=-1, keepdim=True)
    low = torch.tensor([-0.3, -0.2, -0.5], dtype=torch.float64)
    high = torch.tensor([0.4, 0.3, 0.1], dtype=torch.float64)
    near, far, hit = ray_box_bounds(origins, directions, low, high)
    t = torch.linspace(0.0, 5.0, 5001, dtype=torch.float64)
    points = origins[:, None] + t[:, None] * directions[:, None]
    inside = ((points >= low) & (points <= high)).all(-1)
    assert bool((inside.any(-1) == hit).all())
    first = torch.where(inside.any(-1), t[inside.int().argmax(-1)], torch.zeros(()))
    last_index = 5000 - inside.flip(-1).int().argmax(-1)
    last = torch.where(inside.any(-1), t[last_index], torch.zeros(()))
    torch.testing.assert_close(near[hit], first[hit], atol=1e-3, rtol=0)
    torch.testing.assert_close(far[hit], last[hit], atol=1e-3, rtol=0)
