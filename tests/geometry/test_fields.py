"""The field protocol: one output contract, checked by one helper, at every consumer.

An analytic sphere SDF returning [N] works everywhere; [N, 1] is read as [N] everywhere (the
same numbers); any other shape is refused with the same clear message everywhere.
"""

import numpy as np
import pytest
import torch

from lisa_hand.data.images import sphere_trace_views
from lisa_hand.data.scans import sdf_samples
from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov, look_at, pixel_rays
from lisa_hand.geometry.fields import (
    FieldFn,
    SdfFn,
    call_field,
    call_normals,
    call_sdf,
    check_sdf_output,
)
from lisa_hand.geometry.meshing import extract_mesh
from lisa_hand.geometry.rays import ray_sphere_bounds
from lisa_hand.geometry.tracing import sdf_normals, sphere_trace
from lisa_hand.render import (
    LaplaceDensity,
    RenderConfig,
    error_bounded_sampling,
    render_rays,
    sphere_traced_samples,
)
from lisa_hand.render.image import ImageRenderConfig, render_image
from lisa_hand.render.occupancy import build_occupancy_grid

RADIUS = 0.1
BAD_SHAPE = r"sdf_fn must return \[N\] or \[N, 1\] for points \[N, 3\] \(N = \d+\), got \(\d+, 3\)"


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    """points [N, 3] metres -> [N] metres: the sphere of RADIUS at the origin."""
    return points.norm(dim=-1) - RADIUS


def column_sdf(points: torch.Tensor) -> torch.Tensor:
    """The same sphere as an [N, 1] column (a network's last linear layer)."""
    return sphere_sdf(points)[:, None]


def bad_sdf(points: torch.Tensor) -> torch.Tensor:
    """A wrong shape: [N, 3]."""
    return points - 0.0


def field_of(sdf_fn):
    def field_fn(points, directions):
        return sdf_fn(points), 0.5 + 0.5 * torch.sin(40.0 * points)

    return field_fn


def _camera(width=24, height=16) -> Camera:
    rotation, translation = look_at(
        torch.tensor([0.3, -0.2, -0.35], dtype=torch.float64), torch.zeros(3)
    )
    K = intrinsics_from_fov(40.0, width, height, dtype=torch.float64)
    return Camera(K=K.float(), R=rotation.float(), t=translation.float(), width=width,
                  height=height)


def _rays():
    origins, directions = pixel_rays(_camera())
    near, far, hit = ray_sphere_bounds(origins, directions, torch.zeros(3), 1.2 * RADIUS)
    return origins[hit], directions[hit], near[hit], far[hit]


# Every consumer of an SDF callback, as a function of the callback -> some output tensors.
def _render_rays(sdf_fn, sampler):
    origins, directions, near, far = _rays()
    config = RenderConfig(sampler=sampler, num_samples=8, num_samples_extra=4,
                          num_samples_eval=16, max_iters=2)
    out = render_rays(field_of(sdf_fn), sdf_fn, origins, directions, near, far, config,
                      LaplaceDensity(1e-3, 0.0))
    return [out.rgb, out.opacity, out.depth]


def _render_image(sdf_fn, mode, normals="finite_difference", color_weight_threshold=1e-2):
    config = ImageRenderConfig(mode=mode, normals=normals, grid_resolution=16,
                               grid_coarse_resolution=4,
                               color_weight_threshold=color_weight_threshold)
    out = render_image(field_of(sdf_fn), sdf_fn, _camera(), torch.zeros(3), 1.2 * RADIUS, config)
    return [out.rgb, out.depth, out.normals]


def _samplers(sdf_fn):
    origins, directions, near, far = _rays()
    eb = error_bounded_sampling(sdf_fn, origins, directions, near, far, 1e-3, num_samples=8,
                                num_samples_eval=16, num_samples_extra=2, max_iters=2)
    st = sphere_traced_samples(sdf_fn, origins, directions, near, far, 1e-3, num_steps=16)
    return [eb.t_vals, st]


def _grid(sdf_fn):
    grid = build_occupancy_grid(sdf_fn, torch.zeros(3), 0.12, resolution=16,
                                coarse_resolution=4, threshold=0.002)
    return [grid.distance_bound]


def _tracer(sdf_fn):
    origins, directions, near, far = _rays()
    hits = sphere_trace(sdf_fn, origins, directions, near, far)
    points = origins[hits.hit] + hits.t[hits.hit, None] * directions[hits.hit]
    return [hits.t, sdf_normals(sdf_fn, points, "autograd"),
            sdf_normals(sdf_fn, points, "finite_difference")]


def _mesh(sdf_fn):
    mesh = extract_mesh(sdf_fn, (-0.12,) * 3, (0.12,) * 3, 16)
    return [torch.from_numpy(mesh.vertices), torch.from_numpy(mesh.faces)]


def _ground_truth(sdf_fn):
    (view,) = sphere_trace_views(sdf_fn, [_camera()], lambda p: torch.full_like(p, 0.5),
                                 (0.0, 0.0, 0.0), 1.2 * RADIUS, return_normals=True)
    return [torch.from_numpy(np.ascontiguousarray(a)) for a in (view.depth, view.normals)]


def _scan_samples(sdf_fn):
    surface = np.array([[RADIUS, 0.0, 0.0], [0.0, RADIUS, 0.0], [0.0, 0.0, -RADIUS]])
    samples = sdf_samples(sdf_fn, surface, None, 50, 0.01, 0)
    return [torch.from_numpy(samples.sdf)]


CONSUMERS = {
    "render_rays_error_bounded": lambda f: _render_rays(f, "error_bounded"),
    "render_rays_sphere_traced": lambda f: _render_rays(f, "sphere_traced"),
    "render_image_volume": lambda f: _render_image(f, "volume"),
    "render_image_volume_all_colours": lambda f: _render_image(
        f, "volume", color_weight_threshold=0.0
    ),
    "render_image_surface": lambda f: _render_image(f, "surface", normals="autograd"),
    "samplers": _samplers,
    "occupancy_grid": _grid,
    "sphere_trace_and_normals": _tracer,
    "extract_mesh": _mesh,
    "sphere_trace_views": _ground_truth,
    "sdf_samples": _scan_samples,
}


@pytest.mark.parametrize("consumer", sorted(CONSUMERS))
def test_every_consumer_takes_n_and_n_by_1_alike(consumer):
    flat = CONSUMERS[consumer](sphere_sdf)
    column = CONSUMERS[consumer](column_sdf)
    assert any(bool((value != 0).any()) for value in flat)
    for a, b in zip(flat, column, strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize("consumer", sorted(CONSUMERS))
def test_every_consumer_refuses_a_wrong_shape_with_the_same_message(consumer):
    with pytest.raises(ValueError, match=BAD_SHAPE):
        CONSUMERS[consumer](bad_sdf)


def test_call_sdf_contract():
    points = torch.randn(10, 3, dtype=torch.float64)
    values = call_sdf(sphere_sdf, points)
    assert values.shape == (10,) and values.dtype == torch.float64
    assert torch.equal(call_sdf(column_sdf, points), values)
    # Returned in the points' dtype, whatever the callback computes in.
    assert call_sdf(lambda p: sphere_sdf(p).float(), points).dtype == torch.float64
    with pytest.raises(ValueError, match=r"got \(10, 3\)"):
        call_sdf(bad_sdf, points)
    with pytest.raises(ValueError, match=r"got \(\)"):
        call_sdf(lambda p: p.sum(), points)
    with pytest.raises(ValueError, match=r"\(N = 10\), got \(9,\)"):
        call_sdf(lambda p: sphere_sdf(p)[1:], points)
    with pytest.raises(TypeError, match="sdf_fn must return a torch.Tensor, got list"):
        call_sdf(lambda p: [0.0] * len(p), points)
    with pytest.raises(ValueError, match="my_sdf must return"):
        check_sdf_output(torch.zeros(3, 2), 3, "my_sdf")


def test_call_sdf_chunks_the_points():
    sizes = []

    def counting(points):
        sizes.append(points.shape[0])
        return sphere_sdf(points)

    points = torch.randn(10, 3)
    chunked = call_sdf(counting, points, chunk_size=4)
    assert sizes == [4, 4, 2]
    assert torch.equal(chunked, sphere_sdf(points))
    sizes.clear()
    assert call_sdf(counting, points[:0], chunk_size=4).shape == (0,) and sizes == []


def test_call_field_contract():
    points = torch.randn(7, 3)
    directions = torch.nn.functional.normalize(torch.randn(7, 3), dim=-1)
    sdf, rgb = call_field(field_of(column_sdf), points, directions, 3, chunk_size=3)
    assert sdf.shape == (7,) and rgb.shape == (7, 3)
    torch.testing.assert_close(sdf, sphere_sdf(points))
    with pytest.raises(ValueError, match=r"field_fn must return sdf \[N\].*C = 4"):
        call_field(field_of(sphere_sdf), points, directions, 4)
    with pytest.raises(TypeError, match="pair"):
        call_field(lambda p, d: sphere_sdf(p), points, directions)
    empty_sdf, empty_rgb = call_field(field_of(sphere_sdf), points[:0], directions[:0], 3, 4)
    assert empty_sdf.shape == (0,) and empty_rgb.shape == (0, 3)


def test_call_normals_normalises_and_checks():
    points = torch.randn(5, 3)
    normals = call_normals(lambda p: 3.0 * p, points)
    torch.testing.assert_close(normals, points / points.norm(dim=-1, keepdim=True))
    with pytest.raises(ValueError, match=r"normal_fn must return \[N, 3\]"):
        call_normals(lambda p: p[:, :2], points)


def test_the_protocols_describe_plain_functions():
    """A plain function is an SdfFn / FieldFn: the protocols only document the signature."""
    sdf: SdfFn = sphere_sdf
    field: FieldFn = field_of(sphere_sdf)
    points = torch.zeros(2, 3)
    assert sdf(points).shape == (2,) and field(points, points)[1].shape == (2, 3)
    assert "metres" in SdfFn.__call__.__doc__ and "rgb [N, C]" in FieldFn.__call__.__doc__
