import dataclasses
import math

import pytest
import torch

from lisa_hand.render import (
    LaplaceDensity,
    RenderConfig,
    apply_gain_bias,
    ray_sphere_bounds,
    render_rays,
)

from .sphere_scene import RADIUS, make_camera, pinhole_rays, pixel_radius, sphere_sdf

SPHERE_RGB = (0.8, 0.3, 0.2)
BACKGROUND = (0.1, 0.2, 0.9)


def _constant_field(points, directions):
    rgb = torch.tensor(SPHERE_RGB, dtype=points.dtype).expand(points.shape[0], 3)
    return sphere_sdf(points), rgb


def _textured_field(points, directions):
    """Colour varying in space (inside too), so misplaced weights change the image."""
    return sphere_sdf(points), 0.5 + 0.5 * torch.sin(40.0 * points)


def _scene(size, focal, dtype=torch.float32):
    K, R, t, silhouette_px = make_camera(size, focal, dtype)
    origins, directions = pinhole_rays(K, R, t, size, size)
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 1.2 * RADIUS)
    return origins, directions, near, far, hit, silhouette_px


@pytest.mark.parametrize("sampler", ["error_bounded", "sphere_traced", "uniform"])
def test_render_sphere_silhouette_and_colours(sampler):
    size, focal = 40, 50.0
    origins, directions, near, far, hit, silhouette_px = _scene(size, focal)
    config = RenderConfig(sampler=sampler, background=BACKGROUND, chunk_size=300)
    density = LaplaceDensity(beta_init=5e-4, beta_min=1e-5)
    with torch.no_grad():
        out = render_rays(
            _constant_field, sphere_sdf, origins, directions, near, far, config, density
        )
    assert out.rgb.shape == (size * size, 3) and out.weights.shape == (
        size * size,
        96 if sampler != "uniform" else 64,
    )
    radius_px = pixel_radius(size)
    mask = out.opacity > 0.5
    # The mask is the projected disk, up to one pixel at the edge.
    assert mask[radius_px < silhouette_px - 1.0].all()
    assert not mask[radius_px > silhouette_px + 1.0].any()
    area_radius = math.sqrt(mask.sum().item() / math.pi)
    assert abs(area_radius - silhouette_px) < 0.5
    inside = radius_px < silhouette_px - 1.5
    outside = radius_px > silhouette_px + 1.5
    torch.testing.assert_close(
        out.rgb[inside], torch.tensor(SPHERE_RGB).expand(int(inside.sum()), 3), atol=2e-3, rtol=0
    )
    torch.testing.assert_close(
        out.rgb[outside], torch.tensor(BACKGROUND).expand(int(outside.sum()), 3), atol=1e-4, rtol=0
    )
    # Rays that miss the bounds get exactly the background and no opacity.
    assert torch.equal(out.rgb[~hit], torch.tensor(BACKGROUND).expand(int((~hit).sum()), 3))
    assert (out.opacity[~hit] == 0).all() and (out.weights[~hit] == 0).all()


def test_sphere_traced_matches_error_bounded_image():
    size, focal = 48, 60.0
    origins, directions, near, far, _, _ = _scene(size, focal)
    density = LaplaceDensity(beta_init=3e-4, beta_min=1e-5)
    images = {}
    with torch.no_grad():
        for sampler, num_samples, num_extra in [
            ("error_bounded", 64, 32),
            ("sphere_traced", 32, 8),
        ]:
            config = RenderConfig(
                sampler=sampler,
                num_samples=num_samples,
                num_samples_extra=num_extra,
                background=BACKGROUND,
            )
            out = render_rays(
                _textured_field, sphere_sdf, origins, directions, near, far, config, density
            )
            images[sampler] = out.rgb
    mse = ((images["sphere_traced"] - images["error_bounded"]) ** 2).mean()
    psnr = -10.0 * math.log10(mse.item())
    assert psnr > 45.0


def test_gradients_match_finite_differences_float64():
    # Uniform samples do not depend on the parameters, so finite differences see the same samples.
    dtype = torch.float64
    origins, directions, near, far, hit, _ = _scene(12, 15.0, dtype)
    radius = torch.tensor(RADIUS, dtype=dtype, requires_grad=True)
    color = torch.tensor([0.3, 0.6, 0.9], dtype=dtype, requires_grad=True)
    density = LaplaceDensity(beta_init=0.01, beta_min=1e-4).double()
    config = RenderConfig(sampler="uniform", num_samples=48, background=BACKGROUND)
    weights = torch.rand(
        origins.shape[0], 3, generator=torch.Generator().manual_seed(0), dtype=dtype
    )

    def loss_fn():
        def field(points, dirs):
            rgb = color * (1.0 + points)  # depends on the colour parameters and on position
            return points.norm(dim=-1) - radius, rgb

        out = render_rays(field, None, origins, directions, near, far, config, density)
        return (out.rgb * weights).sum() + out.depth.sum()

    loss = loss_fn()
    params = [radius, color, density.beta_raw]
    grads = torch.autograd.grad(loss, params)
    step = 1e-6
    for param, grad in zip(params, grads, strict=True):
        assert torch.isfinite(grad).all() and grad.abs().max() > 0
        flat = param.detach().view(-1)
        for index in range(flat.numel()):
            with torch.no_grad():
                flat[index] += step
                plus = loss_fn().item()
                flat[index] -= 2 * step
                minus = loss_fn().item()
                flat[index] += step
            numeric = (plus - minus) / (2 * step)
            assert grad.view(-1)[index].item() == pytest.approx(numeric, rel=1e-5, abs=1e-7)


def test_gradients_flow_with_error_bounded_sampler():
    origins, directions, near, far, hit, _ = _scene(16, 20.0)
    sdf_offset = torch.zeros((), requires_grad=True)
    color = torch.tensor(SPHERE_RGB, requires_grad=True)
    density = LaplaceDensity(beta_init=2e-3, beta_min=1e-5)

    def field(points, dirs):
        return sphere_sdf(points) + sdf_offset, color.expand(points.shape[0], 3)

    config = RenderConfig(background=BACKGROUND)
    out = render_rays(field, sphere_sdf, origins, directions, near, far, config, density)
    out.rgb.sum().backward()
    for grad in (sdf_offset.grad, color.grad, density.beta_raw.grad):
        assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0
    # Growing the sphere (negative offset) covers more background: d rgb / d offset is the
    # difference background - sphere colour, summed over the silhouette pixels.
    assert sdf_offset.grad.item() * (sum(BACKGROUND) - sum(SPHERE_RGB)) > 0
    assert out.t_vals.grad_fn is None  # sample positions are not differentiated


def test_only_hit_rays_are_evaluated_and_chunking_is_invisible():
    origins, directions, near, far, hit, _ = _scene(20, 25.0)
    density = LaplaceDensity(beta_init=1e-3, beta_min=1e-5)
    seen = []

    def field(points, dirs):
        seen.append(points.shape[0])
        return _textured_field(points, dirs)

    outs = []
    for chunk_size in (37, 4096):
        seen.clear()
        config = RenderConfig(sampler="sphere_traced", chunk_size=chunk_size)
        outs.append(render_rays(field, sphere_sdf, origins, directions, near, far, config, density))
        assert sum(seen) == int(hit.sum()) * config.samples_per_ray
    assert len(seen) == 1
    for name in ("rgb", "opacity", "depth", "weights", "t_vals"):
        torch.testing.assert_close(getattr(outs[0], name), getattr(outs[1], name))
    # A caller-given hit mask: nothing processed, everything background.
    nothing = torch.zeros_like(hit)
    background = torch.rand(hit.shape[0], 3, generator=torch.Generator().manual_seed(1))
    out = render_rays(
        field,
        sphere_sdf,
        origins,
        directions,
        near,
        far,
        RenderConfig(),
        density,
        hit=nothing,
        background=background,
    )
    assert torch.equal(out.rgb, background) and (out.opacity == 0).all()


def test_render_validation():
    origins, directions, near, far, _, _ = _scene(4, 5.0)
    density = LaplaceDensity()
    config = RenderConfig()
    with pytest.raises(ValueError, match="unit length"):
        render_rays(
            _constant_field, sphere_sdf, origins, 2 * directions, near, far, config, density
        )
    with pytest.raises(ValueError, match="sdf_fn"):
        render_rays(_constant_field, None, origins, directions, near, far, config, density)
    with pytest.raises(ValueError, match="near"):
        render_rays(
            _constant_field, sphere_sdf, origins, directions, near[:3], far, config, density
        )
    with pytest.raises(TypeError, match="config"):
        render_rays(_constant_field, sphere_sdf, origins, directions, near, far, {}, density)
    with pytest.raises(ValueError, match="sampler"):
        RenderConfig(sampler="nerf")
    with pytest.raises(ValueError, match="chunk_size"):
        RenderConfig(chunk_size=0)
    with pytest.raises(ValueError, match="eps"):
        RenderConfig(eps=0.0)


def test_apply_gain_bias():
    rgb = torch.tensor([[0.5, 0.25, 1.0], [0.0, 1.0, 0.5]])
    gain = torch.tensor([2.0, 1.0, 0.5])
    bias = torch.tensor([[0.1, 0.0, 0.0], [0.0, -0.5, 0.2]])
    out = apply_gain_bias(rgb, gain, bias)
    torch.testing.assert_close(out, torch.tensor([[1.1, 0.25, 0.5], [0.0, 0.5, 0.45]]))
    # Inference uses the average calibration over cameras.
    per_camera_gain = torch.tensor([[1.0, 1.0, 1.0], [3.0, 1.0, 2.0]])
    torch.testing.assert_close(
        apply_gain_bias(rgb, per_camera_gain.mean(0), torch.zeros(3)),
        rgb * torch.tensor([2.0, 1.0, 1.5]),
    )
    with pytest.raises(ValueError, match="gain"):
        apply_gain_bias(rgb, torch.ones(2), bias)
    with pytest.raises(ValueError, match="bias"):
        apply_gain_bias(rgb, gain, torch.ones(3, 3))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_render_on_cuda_matches_cpu():
    origins, directions, near, far, _, _ = _scene(16, 20.0)
    density = LaplaceDensity(beta_init=1e-3, beta_min=1e-5)
    for sampler in ("error_bounded", "sphere_traced"):
        config = RenderConfig(sampler=sampler)
        cpu = render_rays(
            _textured_field, sphere_sdf, origins, directions, near, far, config, density
        )
        gpu = render_rays(
            _textured_field,
            sphere_sdf,
            origins.cuda(),
            directions.cuda(),
            near.cuda(),
            far.cuda(),
            config,
            density.cuda(),
        )
        torch.testing.assert_close(gpu.rgb.cpu(), cpu.rgb, atol=1e-3, rtol=0)
        density = density.cpu()


def test_grouped_rays_render_as_each_group_alone():
    # Two spheres of different radii (one per group) in one pass: the same images as rendering
    # each alone, stratified too (one generator per group).
    from lisa_hand.render.samplers import GroupGenerators

    K, R, t, _ = make_camera(24, 40.0, torch.float64)
    origins, directions = pinhole_rays(K, R, t, 24, 24)
    radii = torch.tensor([RADIUS, 0.7 * RADIUS], dtype=torch.float64)
    colours = torch.tensor([[0.9, 0.2, 0.1], [0.1, 0.3, 0.8]], dtype=torch.float64)

    def grouped_sdf(points, groups):
        return points.norm(dim=-1) - radii[groups]

    def grouped_field(points, dirs, groups):
        return grouped_sdf(points, groups), colours[groups]

    num = origins.shape[0]
    all_o, all_d = torch.cat([origins, origins]), torch.cat([directions, directions])
    groups = torch.arange(2).repeat_interleave(num)
    near, far, hit = ray_sphere_bounds(all_o, all_d, torch.zeros(3, dtype=torch.float64), 0.15)
    density = LaplaceDensity(beta_init=0.004, beta_min=0.0).double()
    for stratified in (False, True):
        # Chunks change the order of the stratified draws (as for any render): deterministic
        # samples are checked across chunks, stratified ones in one chunk.
        config = RenderConfig(sampler="sphere_traced", num_samples=16, num_samples_extra=4,
                              stratified=stratified, chunk_size=10_000 if stratified else 300)
        generator = GroupGenerators([torch.Generator().manual_seed(s) for s in (3, 4)])
        both = render_rays(grouped_field, grouped_sdf, all_o, all_d, near, far, config, density,
                           hit=hit, generator=generator if stratified else None, groups=groups)
        for group, seed in ((0, 3), (1, 4)):
            rows = slice(group * num, (group + 1) * num)

            def sdf(points, group=group):
                return points.norm(dim=-1) - radii[group]

            def field(points, dirs, group=group):
                return sdf(points), colours[group].expand(points.shape[0], 3)

            alone_config = dataclasses.replace(config, chunk_size=10_000)
            alone = render_rays(field, sdf, origins, directions, near[rows], far[rows],
                                alone_config, density, hit=hit[rows],
                                generator=torch.Generator().manual_seed(seed) if stratified
                                else None)
            torch.testing.assert_close(both.t_vals[rows], alone.t_vals, rtol=0, atol=0)
            torch.testing.assert_close(both.rgb[rows], alone.rgb, rtol=0, atol=1e-12)
            torch.testing.assert_close(both.opacity[rows], alone.opacity, rtol=0, atol=1e-12)
        assert both.opacity[:num].sum() > 1.5 * both.opacity[num:].sum()  # the smaller sphere
    with pytest.raises(ValueError, match="does not take groups"):
        render_rays(grouped_field, grouped_sdf, all_o, all_d, near, far,
                    RenderConfig(sampler="error_bounded"), density, hit=hit, groups=groups)
