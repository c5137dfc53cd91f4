"""The one sphere tracer and SDF-normal helper, against closed-form ray-sphere intersections."""

import math

import numpy as np
import pytest
import torch

from lisa_hand.data.images import sphere_trace_views
from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov, look_at, pixel_rays
from lisa_hand.geometry.rays import ray_sphere_bounds
from lisa_hand.geometry.tracing import sdf_normals, sphere_trace

RADIUS = 0.1  # analytic sphere, metres
CENTRE = (0.0, 0.0, 0.0)
EYE = (0.3, -0.2, -0.35)
WIDTH, HEIGHT = 48, 32


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    """points [N, 3] metres -> exact signed distance [N] to the sphere at CENTRE."""
    return (points - torch.tensor(CENTRE, dtype=points.dtype)).norm(dim=-1) - RADIUS


def scene_camera(dtype=torch.float32) -> Camera:
    """A 40 degree camera at EYE looking at the sphere's centre."""
    centre = torch.tensor(CENTRE, dtype=torch.float64)
    rotation, translation = look_at(torch.tensor(EYE, dtype=torch.float64), centre)
    K = intrinsics_from_fov(40.0, WIDTH, HEIGHT, dtype=torch.float64)
    return Camera(
        K=K.to(dtype), R=rotation.to(dtype), t=translation.to(dtype), width=WIDTH, height=HEIGHT
    )


def closed_form_hits(origins: torch.Tensor, directions: torch.Tensor):
    """First root of ``|o + t d - c| = r`` (unit d), float64: (t [R], hit [R], cos [R]) with
    ``cos`` the cosine between the ray and the normal at the hit (its incidence)."""
    centre = torch.tensor(CENTRE, dtype=torch.float64)
    offset = centre - origins.double()
    along = (offset * directions.double()).sum(-1)
    discriminant = along**2 - (offset * offset).sum(-1) + RADIUS**2
    hit = (discriminant > 0) & (along > 0)
    t = along - torch.sqrt(discriminant.clamp_min(0.0))
    cosine = torch.sqrt(discriminant.clamp_min(0.0)) / RADIUS
    return torch.where(hit, t, torch.zeros_like(t)), hit, cosine


def _rays(dtype=torch.float64):
    origins, directions = pixel_rays(scene_camera(), dtype=dtype)
    centre = torch.tensor(CENTRE, dtype=dtype)
    near, far, _ = ray_sphere_bounds(origins, directions, centre, 1.2 * RADIUS)
    return origins, directions, near, far


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sphere_trace_matches_the_closed_form_intersection(dtype):
    origins, directions, near, far = _rays(dtype)
    t_exact, exact_hit, cosine = closed_form_hits(origins, directions)
    tolerance = 1e-5
    hits = sphere_trace(sphere_sdf, origins, directions, near, far, tolerance=tolerance)
    assert hits.t.dtype == dtype
    # Away from the silhouette (grazing rays may stop within the tolerance of the surface).
    clear = cosine > 0.05
    assert bool((hits.hit == exact_hit)[clear].all())
    assert int(exact_hit.sum()) > 300
    both = hits.hit & exact_hit & clear
    # The hit stops short of the surface by at most the tolerance along the normal.
    error = (hits.t.double() - t_exact)[both]
    bound = tolerance / cosine[both] + (1e-6 if dtype == torch.float32 else 1e-12)
    assert bool((error <= 1e-6).all()) and bool((-error <= bound).all())
    assert float(hits.t[~hits.hit].abs().max()) == 0.0
    assert hits.num_evaluations > int(hits.hit.sum())


def test_sphere_trace_hits_and_lipschitz_allowance():
    origins, directions, near, far = _rays()
    t_exact, exact_hit, _ = closed_form_hits(origins, directions)
    hits = sphere_trace(sphere_sdf, origins, directions, near, far, tolerance=1e-6)
    assert bool((hits.hit == exact_hit).sum() >= exact_hit.numel() - 3)
    both = hits.hit & exact_hit
    assert float((hits.t - t_exact)[both].abs().max()) < 5e-5
    # An SDF that overestimates distances 1.5 times: lipschitz=1.5 makes tracing safe again.
    hits = sphere_trace(
        lambda p: 1.5 * sphere_sdf(p), origins, directions, near, far, tolerance=1e-6, lipschitz=1.5
    )
    both = hits.hit & exact_hit
    assert float((hits.t - t_exact)[both].abs().max()) < 5e-5
    # Without the allowance the overshoot is caught by the secant step: still close.
    hits = sphere_trace(
        lambda p: 1.5 * sphere_sdf(p), origins, directions, near, far, tolerance=1e-6
    )
    both = hits.hit & exact_hit
    assert float((hits.t - t_exact)[both].abs().max()) < 1e-3


def test_sphere_trace_rays_that_miss_and_bad_arguments():
    origins = torch.zeros(2, 3, dtype=torch.float64)
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    origins[:, 2] = -1.0
    near = torch.zeros(2, dtype=torch.float64)
    far = torch.full((2,), 3.0, dtype=torch.float64)
    hits = sphere_trace(lambda p: p.norm(dim=-1) - 0.1, origins, directions, near, far)
    assert hits.hit.tolist() == [True, False]
    assert hits.t[0].item() == pytest.approx(0.9, abs=1e-5) and hits.t[1].item() == 0.0
    with pytest.raises(ValueError, match="origins and directions"):
        sphere_trace(sphere_sdf, origins[:, :2], directions, torch.zeros(2), torch.ones(2))
    with pytest.raises(ValueError, match="near and far"):
        sphere_trace(sphere_sdf, origins, directions, torch.zeros(3), torch.ones(3))
    with pytest.raises(ValueError, match="lipschitz >= 1"):
        sphere_trace(sphere_sdf, origins, directions, torch.zeros(2), torch.ones(2), lipschitz=0.5)


@pytest.mark.parametrize("method", ["autograd", "finite_difference"])
def test_sdf_normals_are_the_sphere_normals(method):
    generator = torch.Generator().manual_seed(1)
    directions = torch.randn(300, 3, generator=generator, dtype=torch.float64)
    directions = directions / directions.norm(dim=-1, keepdim=True)
    points = torch.tensor(CENTRE, dtype=torch.float64) + RADIUS * directions
    normals = sdf_normals(sphere_sdf, points, method, step=1e-5, chunk_size=64)
    torch.testing.assert_close(normals, directions, atol=1e-8, rtol=0)
    with pytest.raises(ValueError, match="method"):
        sdf_normals(sphere_sdf, points, "tetrahedral")
    with pytest.raises(ValueError, match="without gradients"):
        sdf_normals(lambda p: sphere_sdf(p).detach(), points, "autograd")


def test_sdf_normals_finite_differences_match_autograd():
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(200, 3, generator=generator, dtype=torch.float64) * 0.2

    def wavy(p):
        return p.norm(dim=-1) - 0.1 + 0.01 * torch.sin(30.0 * p[:, 0]) * p[:, 1]

    fd = sdf_normals(wavy, points, "finite_difference", step=1e-5)
    ad = sdf_normals(wavy, points, "autograd")
    torch.testing.assert_close(fd, ad, atol=1e-6, rtol=0)


def test_the_data_generator_uses_the_same_tracer():
    """sphere_trace_views' depth and normals are those of sphere_trace and sdf_normals on the
    camera's rays, to the last bit (one tracer, one normal helper)."""
    camera = scene_camera()
    centre = torch.tensor(CENTRE)
    (view,) = sphere_trace_views(
        sphere_sdf, [camera], lambda p: torch.full_like(p, 0.5), CENTRE, 1.2 * RADIUS,
        tolerance=1e-5, return_normals=True,
    )
    origins, directions = pixel_rays(camera)
    near, far, in_bound = ray_sphere_bounds(origins, directions, centre, 1.2 * RADIUS)
    ids = torch.nonzero(in_bound)[:, 0]
    hits = sphere_trace(sphere_sdf, origins[ids], directions[ids], near[ids], far[ids],
                        num_steps=128, tolerance=1e-5, points_per_call=1 << 17)
    mask = torch.zeros(HEIGHT * WIDTH, dtype=torch.bool)
    mask[ids[hits.hit]] = True
    assert np.array_equal(view.mask.reshape(-1), mask.numpy())
    rays = ids[hits.hit]
    t = hits.t[hits.hit]
    points = origins[rays] + t[:, None] * directions[rays]
    depth = t * (directions[rays] * camera.R[2]).sum(-1)
    assert np.array_equal(view.depth.reshape(-1)[rays.numpy()], depth.numpy())
    normals = sdf_normals(sphere_sdf, points, "autograd", chunk_size=1 << 17)
    assert np.array_equal(view.normals.reshape(-1, 3)[rays.numpy()], normals.numpy())
    # ... and the depth is the closed form's, up to the tolerance over the incidence.
    t_exact, _, cosine = closed_form_hits(origins[rays], directions[rays])
    clear = cosine > 0.05
    assert float(((t.double() - t_exact).abs() * cosine)[clear].max()) < 1e-5 + 1e-6
    assert math.isfinite(float(depth.sum()))
