import math

import numpy as np
import pytest
import torch

from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov, look_at, pixel_rays
from lisa_hand.render import LaplaceDensity, ray_sphere_bounds
from lisa_hand.render.image import (
    ImageRenderConfig,
    build_occupancy_grid,
    grid_threshold,
    normals_to_rgb,
    ray_box_bounds,
    render_image,
    save_image_outputs,
    sdf_normals,
    sphere_trace,
)
from lisa_hand.render.turntable import (
    _mp4_backend,
    orbit_cameras,
    render_turntable,
    save_gif,
    save_video,
)

RADIUS = 0.1  # analytic sphere at the origin, metres
EYE = (0.3, -0.2, -0.35)
WIDTH, HEIGHT = 48, 32
BETA = 1e-4  # small enough that the volume silhouette matches the surface (pixels ~7 mm)
# A coarser occupancy grid than the default keeps these tiny renders fast (the default 64^3 grid
# is tested on its own).
SMALL_GRID = {"grid_resolution": 32, "grid_coarse_resolution": 8}


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    return points.norm(dim=-1) - RADIUS


def textured_field(points: torch.Tensor, directions: torch.Tensor):
    """Colour varying in space, so a misplaced sample changes the image."""
    return sphere_sdf(points), 0.5 + 0.5 * torch.sin(40.0 * points)


def _camera(width=WIDTH, height=HEIGHT, dtype=torch.float32) -> Camera:
    rotation, translation = look_at(torch.tensor(EYE, dtype=torch.float64), torch.zeros(3))
    K = intrinsics_from_fov(40.0, width, height, dtype=torch.float64)
    return Camera(
        K=K.to(dtype), R=rotation.to(dtype), t=translation.to(dtype), width=width, height=height
    )


def _analytic_hits(camera: Camera, dtype=torch.float64):
    """Exact ray-sphere intersections: (t [H*W], hit [H*W], points [H*W, 3]) in float64."""
    origins, directions = pixel_rays(camera, dtype=torch.float64)
    near, far, hit = ray_sphere_bounds(
        origins, directions, torch.zeros(3, dtype=torch.float64), RADIUS
    )
    points = origins + near[:, None] * directions
    return near, hit, points


def _render(mode, dtype=torch.float32, **options):
    config = ImageRenderConfig(mode=mode, **SMALL_GRID, **options)
    density = LaplaceDensity(beta_init=BETA, beta_min=0.0)
    center = torch.zeros(3, dtype=dtype)
    return render_image(
        textured_field, sphere_sdf, _camera(), center, 1.2 * RADIUS, config, density.to(dtype)
    )


def _erode(mask: torch.Tensor) -> torch.Tensor:
    """Pixels whose 4 neighbours are also in the mask (away from the silhouette)."""
    inner = mask.clone()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return inner


@pytest.mark.parametrize(
    "mode,culling",
    [("volume", "grid"), ("volume", "box"), ("volume", "sphere"), ("surface", "grid")],
)
def test_rays_that_miss_the_bound_are_never_evaluated(mode, culling):
    camera = _camera()
    bound_radius = 2.0 * RADIUS
    cam_center = camera.center.double()
    evaluated_dirs, evaluated_points = [], []

    def counting_field(points, directions):
        evaluated_points.append(points.detach().double())
        evaluated_dirs.append(directions.detach().double())
        return textured_field(points, directions)

    def counting_sdf(points):
        evaluated_points.append(points.detach().double())
        return sphere_sdf(points)

    config = ImageRenderConfig(mode=mode, culling=culling, normals="none", **SMALL_GRID)
    density = LaplaceDensity(beta_init=1e-3, beta_min=0.0)
    # The grid is built beforehand (its cell centres fill the bounding cube, not the sphere).
    grid = build_occupancy_grid(
        sphere_sdf,
        torch.zeros(3),
        bound_radius,
        resolution=32,
        coarse_resolution=8,
        threshold=grid_threshold(config, 1e-3),
    )
    out = render_image(
        counting_field,
        counting_sdf,
        camera,
        torch.zeros(3),
        bound_radius,
        config,
        density,
        grid=grid,
    )
    points = torch.cat(evaluated_points)
    assert points.shape[0] > 0
    # Every evaluated point lies in the bounding sphere: no work on rays outside it.
    assert float(points.norm(dim=-1).max()) <= bound_radius * (1 + 1e-5)
    directions = torch.cat(evaluated_dirs)
    _, _, on_bound = ray_sphere_bounds(
        cam_center.expand_as(directions),
        directions,
        torch.zeros(3, dtype=torch.float64),
        bound_radius,
    )
    assert bool(on_bound.all())
    origins, all_dirs = pixel_rays(camera)
    _, _, in_bound = ray_sphere_bounds(origins, all_dirs, torch.zeros(3), bound_radius)
    assert out.num_rays_rendered <= int(in_bound.sum())
    if culling == "grid":
        # A kept ray passes a probe in a cell next to an occupied cell: within the threshold
        # plus two cell diagonals of the surface. The bound is twice the sphere: many are culled.
        reach = RADIUS + grid.threshold + 2.0 * math.sqrt(3.0) * grid.cell_size
        _, _, near_surface = ray_sphere_bounds(origins, all_dirs, torch.zeros(3), reach)
        assert out.num_rays_rendered <= int(near_surface.sum())
        assert out.num_rays_rendered < int(in_bound.sum())


def test_surface_and_volume_modes_agree_on_a_sphere():
    surface = _render("surface", normals="none")
    volume = _render("volume", normals="none")
    _, hit, points = _analytic_hits(_camera())
    analytic_mask = hit.reshape(HEIGHT, WIDTH)
    intersection = (surface.mask & volume.mask).sum().item()
    union = (surface.mask | volume.mask).sum().item()
    assert intersection / union > 0.97
    # Surface mode's mask is the analytic one up to the silhouette pixels.
    assert (surface.mask ^ analytic_mask).sum().item() <= 3
    inner = _erode(surface.mask & volume.mask)
    assert inner.sum().item() > 200
    difference = (surface.rgb - volume.rgb)[inner].abs()
    assert float(difference.mean()) < 0.01 and float(difference.max()) < 0.05
    # And both are the field's colour at the analytic hit.
    expected = (0.5 + 0.5 * torch.sin(40.0 * points)).reshape(HEIGHT, WIDTH, 3).float()
    torch.testing.assert_close(surface.rgb[inner], expected[inner], atol=2e-3, rtol=0)
    # Outside the bound and between: the background (black) and zero opacity.
    outside = ~(surface.mask | volume.mask)
    assert float(volume.rgb[_erode(outside)].abs().max()) < 1e-3
    assert float(surface.opacity[outside].abs().max()) == 0.0


def test_colour_skipping_matches_render_rays_everywhere():
    """color_weight_threshold > 0 evaluates far fewer colours and gives the same image."""
    calls = {"skip": 0, "all": 0}

    def field_for(key):
        def field_fn(points, directions):
            calls[key] += points.shape[0]
            return textured_field(points, directions)

        return field_fn

    density = LaplaceDensity(beta_init=1e-3, beta_min=0.0)
    images = {}
    for key, threshold in (("skip", 3e-3), ("all", 0.0)):
        config = ImageRenderConfig(color_weight_threshold=threshold, normals="none", **SMALL_GRID)
        images[key] = render_image(
            field_for(key), sphere_sdf, _camera(), torch.zeros(3), 1.2 * RADIUS, config, density
        )
    assert calls["skip"] < 0.6 * calls["all"]
    mse = float(((images["skip"].rgb - images["all"].rgb) ** 2).mean())
    assert -10.0 * math.log10(mse) > 40.0
    torch.testing.assert_close(images["skip"].opacity, images["all"].opacity, atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    "mode,method",
    [
        ("surface", "finite_difference"),
        ("volume", "finite_difference"),
        ("surface", "autograd"),
        ("surface", "normal_fn"),
    ],
)
def test_normal_map_matches_the_analytic_sphere(mode, method):
    if method == "normal_fn":
        config = ImageRenderConfig(mode=mode, **SMALL_GRID)
        out = render_image(
            textured_field,
            sphere_sdf,
            _camera(),
            torch.zeros(3),
            1.2 * RADIUS,
            config,
            LaplaceDensity(BETA, 0.0),
            normal_fn=lambda p: 3.0 * p,
        )
    else:
        out = _render(mode, normals=method)
    _, hit, points = _analytic_hits(_camera())
    expected = (points / points.norm(dim=-1, keepdim=True)).reshape(HEIGHT, WIDTH, 3)
    mask = out.mask & hit.reshape(HEIGHT, WIDTH)
    assert mask.sum().item() > 300
    cosine = (out.normals.double()[mask] * expected[mask]).sum(-1).clamp(-1.0, 1.0)
    angle_deg = torch.rad2deg(torch.acos(cosine))
    assert float(angle_deg.max()) < 1.0
    torch.testing.assert_close(
        out.normals.norm(dim=-1)[out.mask], torch.ones(int(out.mask.sum())), atol=1e-5, rtol=0
    )
    assert float(out.normals[~out.mask].abs().max()) == 0.0


def test_sdf_normals_finite_differences_match_autograd():
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(200, 3, generator=generator, dtype=torch.float64) * 0.2

    def wavy(p):
        return p.norm(dim=-1) - 0.1 + 0.01 * torch.sin(30.0 * p[:, 0]) * p[:, 1]

    fd = sdf_normals(wavy, points, "finite_difference", step=1e-5)
    ad = sdf_normals(wavy, points, "autograd")
    torch.testing.assert_close(fd, ad, atol=1e-6, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_equals_the_analytic_depth(dtype):
    t_exact, hit, _ = _analytic_hits(_camera())
    t_exact = t_exact.reshape(HEIGHT, WIDTH)
    surface = _render("surface", dtype=dtype, normals="none")
    assert surface.depth.dtype == dtype and surface.rgb.dtype == dtype
    mask = surface.mask & hit.reshape(HEIGHT, WIDTH)
    error = (surface.depth.double() - t_exact)[mask].abs()
    assert float(error.median()) < 2e-5 and float(error.max()) < 3e-4
    assert float(surface.depth[~surface.mask].abs().max()) == 0.0
    # Volume mode: the expected termination depth, within a few beta of the surface.
    volume = _render("volume", dtype=dtype, normals="none")
    inner = _erode(volume.mask & mask)
    error = (volume.depth.double() - t_exact)[inner].abs()
    assert float(error.max()) < 5 * BETA


def test_occupancy_grid_is_conservative_and_bounds_hold_the_surface():
    threshold = 0.004
    grid = build_occupancy_grid(
        sphere_sdf, torch.zeros(3), 0.2, resolution=64, coarse_resolution=16, threshold=threshold
    )
    occupied = grid.occupied.reshape(-1)
    # Every cell that holds a point of the shell |sdf| <= threshold is occupied (random points).
    generator = torch.Generator().manual_seed(0)
    points = grid.low + 0.4 * torch.rand(200_000, 3, generator=generator, dtype=torch.float64)
    cells = ((points - grid.low) / grid.cell_size).floor().long().clamp(0, 63)
    flat = (cells * torch.tensor([64 * 64, 64, 1])).sum(-1)
    in_shell = sphere_sdf(points).abs() <= threshold
    assert in_shell.sum() > 1000 and bool(occupied[flat[in_shell]].all())
    # ... and only those that may: a cell whose centre is farther than the threshold plus the
    # half diagonal from the surface is empty.
    index = torch.stack(torch.meshgrid(*[torch.arange(64)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres = grid.low + (index + 0.5) * grid.cell_size
    far_cells = sphere_sdf(centres).abs() > threshold + 0.5 * math.sqrt(3) * grid.cell_size + 1e-6
    assert not bool(occupied[far_cells].any())
    assert grid.num_evaluations < 0.4 * 64**3  # the coarse pass skipped most of the cube
    # Rays: the culled ones never come within the threshold of the surface; the others' bounds
    # contain the first surface crossing.
    origins, directions = pixel_rays(_camera(64, 48))
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 0.2)
    origins, directions, near, far = origins[hit], directions[hit], near[hit], far[hit]
    new_near, new_far, keep = grid.ray_bounds(origins, directions, near, far, chunk_size=1000)
    samples = near[:, None] + (far - near)[:, None] * torch.linspace(0, 1, 2000)
    sdf = sphere_sdf(origins[:, None] + samples[..., None] * directions[:, None])
    assert bool((sdf[~keep].amin(dim=-1) > threshold).all())
    t_surface, surface_hit = _analytic_entry(origins, directions)
    assert bool(keep[surface_hit].all())
    assert bool((new_near[surface_hit] <= t_surface[surface_hit]).all())
    assert bool((new_far[surface_hit] >= t_surface[surface_hit]).all())
    assert bool((new_near[keep] >= near[keep]).all() and (new_far[keep] <= far[keep]).all())
    # The start moved up to the surface: the sphere tracer skips less empty space.
    gap_before = (t_surface - near)[surface_hit].mean()
    gap_after = (t_surface - new_near)[surface_hit].mean()
    assert float(gap_after) < 0.3 * float(gap_before)


def _analytic_entry(origins, directions):
    """Distance [R] to the analytic sphere and whether each ray hits it [R]."""
    near, _, hit = ray_sphere_bounds(
        origins.double(), directions.double(), torch.zeros(3, dtype=torch.float64), RADIUS
    )
    return near.float(), hit


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


def test_sphere_trace_hits_and_lipschitz_allowance():
    origins, directions = pixel_rays(_camera(), dtype=torch.float64)
    near, far, hit = ray_sphere_bounds(
        origins, directions, torch.zeros(3, dtype=torch.float64), 0.12
    )
    t_exact, exact_hit, _ = _analytic_hits(_camera())
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


def test_orbit_cameras_look_at_the_centre_and_are_evenly_spaced():
    center = torch.tensor([0.1, -0.05, 0.3])
    up = torch.tensor([0.0, 0.0, 2.0])
    num_views, radius, elevation = 7, 0.5, 20.0
    cameras = orbit_cameras(num_views, center, radius, elevation, 64, 48, 35.0, up)
    assert [c.name for c in cameras] == [f"orbit{i:03d}" for i in range(num_views)]
    offsets = torch.stack([c.center.double() for c in cameras]) - center.double()
    torch.testing.assert_close(
        offsets.norm(dim=-1), torch.full((num_views,), radius, dtype=torch.float64)
    )
    up_unit = up.double() / up.double().norm()
    heights = offsets @ up_unit
    torch.testing.assert_close(
        heights,
        torch.full((num_views,), radius * math.sin(math.radians(elevation)), dtype=torch.float64),
        atol=1e-6,
        rtol=0,
    )
    horizontal = offsets - heights[:, None] * up_unit
    for index, camera in enumerate(cameras):
        pixels, depth = camera.project(center[None])
        torch.testing.assert_close(pixels[0], torch.tensor([32.0, 24.0]), atol=1e-3, rtol=0)
        torch.testing.assert_close(depth[0], torch.tensor(radius), atol=1e-5, rtol=0)
        # Image "up" is the orbit axis: a point above the centre projects higher (smaller v).
        above, _ = camera.project((center + 0.01 * up_unit.float())[None])
        assert float(above[0, 1]) < 24.0 - 0.1
        following = horizontal[(index + 1) % num_views]
        cosine = (horizontal[index] @ following) / (horizontal[index].norm() * following.norm())
        step = math.degrees(math.acos(float(cosine.clamp(-1, 1))))
        assert abs(step - 360.0 / num_views) < 1e-4
        # Counter-clockwise about up (right-handed).
        assert float(torch.linalg.cross(horizontal[index], following) @ up_unit) > 0
    with pytest.raises(ValueError, match="elevation_deg"):
        orbit_cameras(3, center, radius, 90.0)
    with pytest.raises(ValueError, match="num_views"):
        orbit_cameras(0, center, radius)


def test_turntable_gif_has_every_frame(tmp_path):
    import imageio.v3 as iio

    cameras = orbit_cameras(5, (0.0, 0.0, 0.0), 0.5, 10.0, 32, 24, 40.0)
    frames = render_turntable(
        textured_field,
        sphere_sdf,
        cameras,
        torch.zeros(3),
        0.12,
        ImageRenderConfig(mode="surface", **SMALL_GRID),
        kind="rgb+normals",
    )
    assert len(frames) == 5 and frames[0].shape == (24, 64, 3) and frames[0].dtype == np.uint8
    # The pattern turns with the view: frames differ (Pillow would merge identical ones).
    assert all(np.abs(frames[i].astype(int) - frames[i + 1]).mean() > 1.0 for i in range(4))
    path = save_gif(tmp_path / "turn.gif", frames, fps=10)
    read = iio.imread(path, index=None)
    assert read.shape[0] == 5 and read.shape[1:3] == (24, 64)
    # Palette quantisation only.
    assert np.abs(read[2, ..., :3].astype(int) - frames[2]).mean() < 6.0
    assert [p.name for p in tmp_path.iterdir()] == ["turn.gif"]  # no temporary left behind
    with pytest.raises(ValueError, match="uint8"):
        save_gif(tmp_path / "bad.gif", [np.zeros((4, 4, 3))])
    if _mp4_backend() is None:
        with pytest.raises(OSError, match="imageio-ffmpeg"):
            save_video(tmp_path / "turn.mp4", frames)
        assert not (tmp_path / "turn.mp4").exists()


def test_saved_outputs_encode_normals(tmp_path):
    import imageio.v3 as iio

    out = _render("surface")
    paths = save_image_outputs(tmp_path, out, "sphere")
    assert set(paths) == {"rgb", "normals", "mask", "depth"}
    normals_png = iio.imread(paths["normals"])
    expected = (normals_to_rgb(out.normals, out.mask) * 255).round().to(torch.uint8).numpy()
    assert np.array_equal(normals_png, expected)
    decoded = normals_png[out.mask.numpy()].astype(np.float64) / 255.0 * 2.0 - 1.0
    decoded /= np.linalg.norm(decoded, axis=-1, keepdims=True)
    cosine = (decoded * out.normals[out.mask].double().numpy()).sum(-1)
    assert cosine.min() > math.cos(math.radians(1.0))
    torch.testing.assert_close(torch.from_numpy(np.load(paths["depth"])), out.depth.float())
    assert np.array_equal(iio.imread(paths["mask"]) > 0, out.mask.numpy())


def test_invalid_inputs_name_the_argument():
    with pytest.raises(ValueError, match="mode"):
        ImageRenderConfig(mode="mesh")
    with pytest.raises(ValueError, match="grid_coarse_resolution"):
        ImageRenderConfig(grid_resolution=64, grid_coarse_resolution=12)
    with pytest.raises(ValueError, match="bound_center"):
        render_image(textured_field, sphere_sdf, _camera(), torch.zeros(2), 0.1)
    with pytest.raises(ValueError, match="bound_radius"):
        render_image(textured_field, sphere_sdf, _camera(), torch.zeros(3), 0.0)
    with pytest.raises(ValueError, match="sdf_fn must return"):
        render_image(textured_field, lambda p: p, _camera(), torch.zeros(3), 0.12)
