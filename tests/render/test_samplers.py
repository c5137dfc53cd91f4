import math

import pytest
import torch

from lisa_hand.render import (
    composite,
    distance_lower_bound,
    error_bounded_sampling,
    opacity_error_bound,
    ray_sphere_bounds,
    sphere_traced_samples,
    uniform_samples,
    volsdf_density,
)

from .sphere_scene import RADIUS, sphere_sdf


def _fan_of_rays(num_rays: int, dtype=torch.float64):
    """Rays from (0, 0, -0.5) through (h, 0, 0), h from 0 (head-on) past the silhouette."""
    offsets = torch.linspace(0.0, 1.05 * RADIUS, num_rays, dtype=dtype)
    origins = torch.tensor([0.0, 0.0, -0.5], dtype=dtype).expand(num_rays, 3)
    targets = torch.stack([offsets, torch.zeros_like(offsets), torch.zeros_like(offsets)], -1)
    directions = targets - origins
    directions = directions / directions.norm(dim=-1, keepdim=True)
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 1.2 * RADIUS)
    assert hit.all()
    return origins, directions, near, far


def _reference_optical_depth(origins, directions, near, far, beta, num=40_000):
    """Dense float64 trapezoid integral of sigma: (t [R, num], R(t) [R, num])."""
    unit = torch.linspace(0.0, 1.0, num, dtype=torch.float64)
    t_dense = near[:, None] + (far - near)[:, None] * unit
    points = origins[:, None, :] + t_dense[..., None] * directions[:, None, :]
    sigma = volsdf_density(sphere_sdf(points), beta)
    steps = 0.5 * (sigma[:, 1:] + sigma[:, :-1]) * (t_dense[:, 1:] - t_dense[:, :-1])
    depth = torch.cat([torch.zeros_like(steps[:, :1]), torch.cumsum(steps, -1)], -1)
    return t_dense, depth


def test_uniform_samples_deterministic_and_stratified():
    near = torch.tensor([0.0, 1.0])
    far = torch.tensor([1.0, 3.0])
    t_vals = uniform_samples(near, far, 4)
    assert t_vals.tolist() == [[0.0, 0.25, 0.5, 0.75], [1.0, 1.5, 2.0, 2.5]]
    gen = torch.Generator().manual_seed(3)
    jittered = uniform_samples(near, far, 4, stratified=True, generator=gen)
    bin_width = ((far - near) / 4)[:, None]
    assert ((jittered >= t_vals) & (jittered < t_vals + bin_width)).all()
    again = uniform_samples(near, far, 4, True, torch.Generator().manual_seed(3))
    assert torch.equal(jittered, again)
    assert not torch.equal(jittered, t_vals)
    with pytest.raises(ValueError, match="num_samples"):
        uniform_samples(near, far, 0)
    with pytest.raises(ValueError, match="far"):
        uniform_samples(near, far[:1], 3)


@pytest.mark.parametrize("eps", [0.1, 0.03])
def test_error_bounded_sampler_opacity_error_below_eps(eps):
    beta = 3e-4
    origins, directions, near, far = _fan_of_rays(48)
    result = error_bounded_sampling(sphere_sdf, origins, directions, near, far, beta, eps=eps)

    t_vals = result.t_vals
    assert t_vals.shape == (48, 96) and t_vals.dtype == torch.float64
    assert (t_vals[:, 1:] >= t_vals[:, :-1]).all()
    assert (t_vals >= near[:, None] - 1e-12).all() and (t_vals <= far[:, None] + 1e-12).all()
    assert result.converged.float().mean() >= 0.9
    assert torch.equal(
        result.beta_plus[result.converged],
        torch.full_like(result.beta_plus, beta)[result.converged],
    )
    assert (result.error_bound <= eps).all()

    # VolSDF's guarantee: on the set T, the Riemann opacity with beta+ is within eps of the true
    # opacity with beta+, at every t in [near, far] (checked on a dense grid).
    beta_plus = result.beta_plus[:, None]
    t_dense, depth_ref = _reference_optical_depth(origins, directions, near, far, beta_plus)
    t_bound, sdf_bound = result.t_bound, result.sdf_bound
    sigma = volsdf_density(sdf_bound, beta_plus)
    riemann = torch.cumsum(sigma[:, :-1] * torch.diff(t_bound, dim=-1), -1)
    riemann = torch.cat([torch.zeros_like(riemann[:, :1]), riemann], -1)
    k = torch.clamp(torch.searchsorted(t_bound, t_dense, right=True) - 1, 0, t_bound.shape[1] - 1)
    riemann_dense = riemann.gather(-1, k) + (t_dense - t_bound.gather(-1, k)) * sigma.gather(-1, k)
    error = (torch.exp(-riemann_dense) - torch.exp(-depth_ref)).abs()
    assert error.max() <= eps
    assert error.max() > 1e-4  # the bound is not tested vacuously: T is a coarse set

    # The final samples render the true opacity (with beta) within eps on converged rays.
    _, depth_beta = _reference_optical_depth(origins, directions, near, far, beta)
    points = origins[:, None] + t_vals[..., None] * directions[:, None]
    sigma_final = volsdf_density(sphere_sdf(points), beta)
    out = composite(sigma_final, torch.ones(48, 96, 1, dtype=torch.float64), t_vals, far)
    opacity_ref = 1.0 - torch.exp(-depth_beta[:, -1])
    assert (out.opacity - opacity_ref)[result.converged].abs().max() <= eps


def test_sphere_traced_samples_concentrate_at_the_surface():
    beta = 5e-4
    origins, directions, near, far = _fan_of_rays(24, torch.float32)
    origins = torch.cat([origins, torch.tensor([[0.0, 0.5, -0.5]])])  # passes far from the sphere
    miss_dir = torch.tensor([[0.0, 0.0, 1.0]])
    directions = torch.cat([directions, miss_dir])
    near = torch.cat([near, torch.tensor([0.0])])
    far = torch.cat([far, torch.tensor([1.0])])
    t_vals = sphere_traced_samples(
        sphere_sdf, origins, directions, near, far, beta, num_samples=32, num_uniform=8
    )
    assert t_vals.shape == (25, 40)
    assert (t_vals[:, 1:] >= t_vals[:, :-1]).all()
    assert (t_vals >= near[:, None]).all() and (t_vals <= far[:, None]).all()
    # Head-on ray: the surface is at t = 0.4; all band samples lie within [-9, +16] beta of it.
    band = (t_vals[0] > 0.4 - 9 * beta) & (t_vals[0] < 0.4 + 16 * beta + 1e-6)
    assert band.sum() >= 32
    # The far ray gets evenly spaced samples over [near, far].
    torch.testing.assert_close(t_vals[-1], torch.arange(40) / 40.0)


def test_sphere_traced_opacity_matches_dense_reference():
    beta = 3e-4
    origins, directions, near, far = _fan_of_rays(48)
    t_vals = sphere_traced_samples(sphere_sdf, origins, directions, near, far, beta)
    points = origins[:, None] + t_vals[..., None] * directions[:, None]
    sigma = volsdf_density(sphere_sdf(points), beta)
    out = composite(sigma, torch.ones(*t_vals.shape, 1, dtype=torch.float64), t_vals, far)
    _, depth_ref = _reference_optical_depth(origins, directions, near, far, beta)
    opacity_ref = 1.0 - torch.exp(-depth_ref[:, -1])
    assert (out.opacity - opacity_ref).abs().max() < 5e-3
    # Grazing rays are part of the fan: opacities strictly between 0.05 and 0.95 occur.
    assert ((opacity_ref > 0.05) & (opacity_ref < 0.95)).any()
    # Depth of head-on-ish rays: the first hit of the exact sphere, within a few beta.
    offsets = torch.linspace(0.0, 1.05 * RADIUS, 48, dtype=torch.float64)
    inner = offsets < 0.9 * RADIUS
    to_center = -origins
    t_mid = (to_center * directions).sum(-1)
    half = torch.sqrt(torch.clamp(RADIUS**2 - (to_center.norm(dim=-1) ** 2 - t_mid**2), min=0))
    assert (out.depth - (t_mid - half))[inner].abs().max() < 5 * beta / math.cos(math.asin(0.9))


def test_sphere_traced_band_reaches_far_when_the_steps_run_out():
    # Two spheres of radius 5 cm on a ray along +z: the ray grazes the first one's shell (6 mm
    # from its surface, inside the 8 beta = 8 mm shell, no hit), leaves it at the 16th step and
    # runs out of steps (18) before the second sphere, whose surface it would reach at
    # t = 0.45 m (29th step). The unexplored rest of the ray must stay in the band, which must
    # not end at the last exit from the first shell (it did: the second sphere got no sample).
    beta, radius = 1e-3, 0.05
    centre_a = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64)
    centre_b = torch.tensor([radius + 6e-3, 0.0, 0.3], dtype=torch.float64)

    def two_spheres(points):
        to_a = (points - centre_a).norm(dim=-1)
        to_b = (points - centre_b).norm(dim=-1)
        return torch.minimum(to_a, to_b) - radius

    origins = torch.tensor([[radius + 6e-3, 0.0, -0.2]], dtype=torch.float64)
    directions = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    near, far = torch.tensor([0.0], dtype=torch.float64), torch.tensor([0.6], dtype=torch.float64)
    t_vals = sphere_traced_samples(
        two_spheres,
        origins,
        directions,
        near,
        far,
        beta,
        num_samples=64,
        num_uniform=0,
        num_steps=18,
    )
    t_surface_b = 0.45
    assert t_vals.max() > t_surface_b + 5 * beta
    points = origins[:, None] + t_vals[..., None] * directions[:, None]
    sigma = volsdf_density(two_spheres(points), beta)
    out = composite(sigma, torch.ones(*t_vals.shape, 1, dtype=torch.float64), t_vals, far)
    assert out.opacity.item() > 0.99  # the second sphere is opaque


def test_distance_lower_bound_hand_cases():
    # Columns: segment [0, 2] with radii (sqrt2, sqrt2) -> height 1; segment 1 with radii
    # (1, 3) -> obtuse at the first end, d* = 1; radii (3, 1) -> d* = 1; radii (1, 1) on a
    # segment of 3 -> balls do not cover it, 0; a sign change -> 0.
    t_vals = torch.tensor(
        [[0.0, 2.0], [0.0, 1.0], [0.0, 1.0], [0.0, 3.0], [0.0, 1.0]], dtype=torch.float64
    )
    root2 = math.sqrt(2.0)
    sdf = torch.tensor(
        [[root2, root2], [1.0, 3.0], [-3.0, -1.0], [1.0, 1.0], [0.5, -0.7]], dtype=torch.float64
    )
    d_star = distance_lower_bound(t_vals, sdf)[:, 0]
    assert d_star.tolist() == pytest.approx([1.0, 1.0, 1.0, 0.0, 0.0], abs=1e-12)


def test_distance_lower_bound_is_a_valid_and_tight_bound_for_a_sphere():
    gen = torch.Generator().manual_seed(0)
    origins, directions, near, far = _fan_of_rays(32)
    t_vals = (
        near[:, None]
        + (far - near)[:, None]
        * torch.rand(32, 9, generator=gen, dtype=torch.float64).sort(-1).values
    )
    points = origins[:, None] + t_vals[..., None] * directions[:, None]
    d_star = distance_lower_bound(t_vals, sphere_sdf(points))
    # True distance from each segment to the sphere, by dense sampling of the segment.
    frac = torch.linspace(0.0, 1.0, 2001, dtype=torch.float64)
    seg_t = t_vals[:, :-1, None] + (t_vals[:, 1:] - t_vals[:, :-1])[..., None] * frac
    seg_points = origins[:, None, None] + seg_t[..., None] * directions[:, None, None]
    true = sphere_sdf(seg_points).abs().amin(-1)
    assert (d_star <= true + 1e-12).all()
    # Where the surface is not crossed, the bound captures most of the true distance.
    positive = true > 1e-3
    assert (d_star[positive] / true[positive]).median() > 0.5


def test_opacity_error_bound_hand_computed():
    # Section 0: length 1, radii (2, 1): obtuse at the second end, d* = 1.
    # Section 1: length 1.2, radii (1, 1): triangle height sqrt(1 - 0.6^2) = 0.8.
    t_vals = torch.tensor([[0.0, 1.0, 2.2]], dtype=torch.float64)
    sdf = torch.tensor([[2.0, 1.0, 1.0]], dtype=torch.float64)
    beta = torch.tensor(0.5, dtype=torch.float64)
    assert distance_lower_bound(t_vals, sdf)[0].tolist() == pytest.approx([1.0, 0.8], abs=1e-12)
    bound, per_section = opacity_error_bound(t_vals, sdf, beta)
    sigma0 = (1 / 0.5) * 0.5 * math.exp(-2.0 / 0.5)  # alpha Psi(-s) with alpha = 1 / beta
    e1 = 1.0**2 * math.exp(-1.0 / 0.5) / (4 * 0.5**2)
    e2 = e1 + 1.2**2 * math.exp(-0.8 / 0.5) / (4 * 0.5**2)
    expected = [math.expm1(e1), math.expm1(e2) * math.exp(-sigma0 * 1.0)]
    assert per_section[0].tolist() == pytest.approx(expected, rel=1e-12)
    assert bound.item() == pytest.approx(max(expected), rel=1e-12)


@pytest.mark.parametrize("num_bound", [16, 64, 256])
def test_opacity_error_bound_holds_for_uniform_sets(num_bound):
    # VolSDF Theorem 2: |O(t) - O_hat(t)| <= B on [near, far], whatever T is.
    beta = 2e-3
    origins, directions, near, far = _fan_of_rays(32)
    unit = torch.linspace(0.0, 1.0, num_bound, dtype=torch.float64)
    t_bound = near[:, None] + (far - near)[:, None] * unit
    points = origins[:, None] + t_bound[..., None] * directions[:, None]
    sdf_bound = sphere_sdf(points)
    bound, _ = opacity_error_bound(t_bound, sdf_bound, torch.tensor(beta, dtype=torch.float64))
    t_dense, depth_ref = _reference_optical_depth(origins, directions, near, far, beta)
    sigma = volsdf_density(sdf_bound, beta)
    riemann = torch.cumsum(sigma[:, :-1] * torch.diff(t_bound, dim=-1), -1)
    riemann = torch.cat([torch.zeros_like(riemann[:, :1]), riemann], -1)
    k = torch.clamp(torch.searchsorted(t_bound, t_dense, right=True) - 1, 0, num_bound - 1)
    riemann_dense = riemann.gather(-1, k) + (t_dense - t_bound.gather(-1, k)) * sigma.gather(-1, k)
    error = (torch.exp(-riemann_dense) - torch.exp(-depth_ref)).abs().amax(-1)
    assert (error <= bound + 1e-9).all()


@pytest.mark.parametrize("sampler", [error_bounded_sampling, sphere_traced_samples])
def test_stratified_samples_are_reproducible_and_jittered(sampler):
    origins, directions, near, far = _fan_of_rays(8, torch.float32)

    def run(stratified, seed):
        gen = torch.Generator().manual_seed(seed)
        out = sampler(
            sphere_sdf, origins, directions, near, far, 1e-3, stratified=stratified, generator=gen
        )
        return out.t_vals if hasattr(out, "t_vals") else out

    first, again, other = run(True, 0), run(True, 0), run(True, 1)
    plain = run(False, 0)
    assert torch.equal(first, again) and not torch.equal(first, other)
    assert not torch.equal(first, plain) and first.shape == plain.shape
    assert (first[:, 1:] >= first[:, :-1]).all()
    assert (first >= near[:, None]).all() and (first <= far[:, None]).all()


def test_sphere_traced_full_steps_find_the_surface_in_fewer_calls():
    # Rays past a sphere at offsets from its centre, many grazing: with full steps after the
    # shell entry (and a hit within 1 beta) every hitting ray's band still holds its exact
    # entry point, in fewer SDF evaluations.
    from lisa_hand.render.sphere_tracing import sphere_traced_samples

    offsets = torch.linspace(0.0, 0.11, 200, dtype=torch.float64)
    origins = torch.stack([offsets, torch.zeros_like(offsets), torch.full_like(offsets, -0.5)], 1)
    directions = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand(200, 3)
    near, far = torch.full_like(offsets, 0.3), torch.full_like(offsets, 0.7)
    radius, beta = 0.1, 0.002
    calls = []

    def sdf(points):
        calls.append(points.shape[0])
        return points.norm(dim=-1) - radius

    hits = offsets < radius
    depth = 0.5 - torch.sqrt((radius**2 - offsets[hits] ** 2).clamp_min(0))  # exact entry
    results = {}
    for full in (False, True):
        calls.clear()
        t_vals = sphere_traced_samples(sdf, origins, directions, near, far, beta, num_samples=16,
                                       num_uniform=0, num_steps=64, band_outside=4.0,
                                       band_inside=8.0, full_steps=full,
                                       hit_tolerance=1.0 if full else 0.1)
        band = t_vals[hits]
        assert bool(((band[:, 0] <= depth) & (band[:, -1] >= depth)).all()), full
        results[full] = sum(calls)
    assert results[True] < results[False]
