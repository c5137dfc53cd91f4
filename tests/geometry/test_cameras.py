import json
import math

import pytest
import torch

from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.geometry.cameras import (
    Camera,
    camera_center,
    intrinsics_from_fov,
    load_cameras,
    look_at,
    make_rig,
    pixel_centers,
    pixel_rays,
    project_points,
    save_cameras,
)


def _simple_camera(dtype=torch.float64) -> Camera:
    K = torch.tensor([[500.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]], dtype=dtype)
    R = axis_angle_to_matrix(torch.tensor([0.1, -0.2, 0.3], dtype=dtype))
    t = torch.tensor([0.05, -0.02, 1.0], dtype=dtype)
    return Camera(K=K, R=R, t=t, width=640, height=480, name="test")


def test_project_points_matches_hand_computation():
    # Identity rotation: x_cam = x + t, u = fx x/z + cx, v = fy y/z + cy.
    K = torch.tensor([[500.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    R = torch.eye(3)
    t = torch.tensor([0.1, 0.0, 2.0])
    points = torch.tensor([[0.0, 0.0, 0.0], [0.2, -0.1, 0.5]])
    pixels, depth = project_points(K, R, t, points)
    expected_pixels = torch.tensor([[500.0 * 0.1 / 2.0 + 320.0, 240.0],
                                    [500.0 * 0.3 / 2.5 + 320.0, 400.0 * -0.1 / 2.5 + 240.0]])
    torch.testing.assert_close(pixels, expected_pixels)
    torch.testing.assert_close(depth, torch.tensor([2.0, 2.5]))


def test_project_points_rotation_and_batch():
    # 90 degrees about y: x_cam = (z, y, -x); a point at world (-1, 0, 0) + t lands 1 m ahead.
    R = axis_angle_to_matrix(torch.tensor([0.0, math.pi / 2, 0.0], dtype=torch.float64))
    K = torch.eye(3, dtype=torch.float64)
    t = torch.zeros(3, dtype=torch.float64)
    points = torch.tensor([[[-1.0, 0.5, 0.25]]], dtype=torch.float64)
    pixels, depth = project_points(K, R, t, points)
    torch.testing.assert_close(depth, torch.tensor([[1.0]], dtype=torch.float64))
    torch.testing.assert_close(pixels, torch.tensor([[[0.25, 0.5]]], dtype=torch.float64))
    # Batch of two cameras broadcast over one point set.
    Ks = torch.stack([K, 2 * K]).clone()
    Ks[:, 2, 2] = 1.0
    pixels_b, depth_b = project_points(Ks, R.expand(2, 3, 3), t.expand(2, 3), points)
    assert pixels_b.shape == (2, 1, 2) and depth_b.shape == (2, 1)
    torch.testing.assert_close(pixels_b[1], 2 * pixels_b[0])


def test_camera_center_is_fixed_by_extrinsics():
    camera = _simple_camera()
    center = camera_center(camera.R, camera.t)
    x_cam = camera.R @ center + camera.t
    torch.testing.assert_close(x_cam, torch.zeros(3, dtype=torch.float64))


def test_pixel_rays_pass_through_projected_point():
    camera = _simple_camera()
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(50, 3, generator=generator, dtype=torch.float64) * 0.1
    pixels, depth = camera.project(points)
    origins, directions = pixel_rays(camera, pixels)
    torch.testing.assert_close(directions.norm(dim=-1), torch.ones(50, dtype=torch.float64))
    # The point lies on the ray at distance |p - o| from the origin.
    to_point = points - origins
    distance = to_point.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(origins + distance * directions, points, atol=1e-10, rtol=0)
    assert bool((depth > 0).all())


def test_full_image_rays_are_row_major_pixel_centres():
    camera = _simple_camera().to(dtype=torch.float32)
    small = Camera(K=camera.K * torch.tensor([[0.1], [0.1], [1.0]]), R=camera.R, t=camera.t,
                   width=64, height=48)
    origins, directions = pixel_rays(small)
    assert origins.shape == (64 * 48, 3) and directions.shape == (64 * 48, 3)
    centres = pixel_centers(64, 48)
    # Entry v * W + u is pixel (u + 0.5, v + 0.5).
    torch.testing.assert_close(centres[5 * 64 + 7], torch.tensor([7.5, 5.5]))
    _, expected = pixel_rays(small, centres)
    torch.testing.assert_close(directions, expected, atol=1e-6, rtol=0)
    # Projecting points along the rays gives back the pixel centres.
    projected, _ = small.project(origins + 0.7 * directions)
    torch.testing.assert_close(projected, centres, atol=2e-3, rtol=0)


def test_look_at_puts_target_at_principal_point():
    eye = torch.tensor([0.3, 0.2, -0.5], dtype=torch.float64)
    target = torch.tensor([0.01, -0.02, 0.03], dtype=torch.float64)
    R, t = look_at(eye, target)
    torch.testing.assert_close(R @ R.T, torch.eye(3, dtype=torch.float64))
    assert torch.linalg.det(R).item() == pytest.approx(1.0)
    K = intrinsics_from_fov(50.0, 200, 100, dtype=torch.float64)
    pixels, depth = project_points(K, R, t, target[None])
    torch.testing.assert_close(pixels[0], torch.tensor([100.0, 50.0], dtype=torch.float64))
    assert depth.item() == pytest.approx((target - eye).norm().item())
    torch.testing.assert_close(camera_center(R, t), eye)
    # World up (+y) appears as image up (negative v) for a point above the target.
    above, _ = project_points(K, R, t, (target + torch.tensor([0.0, 0.05, 0.0],
                                                              dtype=torch.float64))[None])
    assert above[0, 1] < 50.0


def test_look_at_rejects_up_parallel_to_view():
    with pytest.raises(ValueError, match="up"):
        look_at(torch.tensor([0.0, 1.0, 0.0]), torch.zeros(3), torch.tensor([0.0, 1.0, 0.0]))


def test_intrinsics_from_fov_closed_form():
    K = intrinsics_from_fov(90.0, 1000, 600, dtype=torch.float64)
    # tan(45 deg) = 1 -> fx = W / 2.
    torch.testing.assert_close(K, torch.tensor([[500.0, 0.0, 500.0], [0.0, 500.0, 300.0],
                                                [0.0, 0.0, 1.0]], dtype=torch.float64))


def test_make_rig_cameras_see_the_target_and_a_hand():
    target = torch.tensor([0.02, -0.01, 0.5])
    rig = make_rig(24, target)
    assert len(rig) == 24 and len({camera.name for camera in rig}) == 24
    # A 20 cm hand fits in a ball of radius 10 cm around the target: sample its sphere.
    generator = torch.Generator().manual_seed(0)
    sphere = torch.randn(500, 3, generator=generator)
    sphere = 0.1 * sphere / sphere.norm(dim=-1, keepdim=True) + target
    centers = torch.stack([camera.center for camera in rig])
    for camera in rig:
        pixels, depth = camera.project(torch.cat([target[None], sphere]))
        assert bool((depth > 0).all())
        assert 0 < pixels[:, 0].min() and pixels[:, 0].max() < camera.width
        assert 0 < pixels[:, 1].min() and pixels[:, 1].max() < camera.height
        # Jitter is small: the target stays near the image centre.
        assert (pixels[0] - torch.tensor([512.0, 333.5])).norm() < 80.0
        # ... and the hand fills a good part of the frame (over half of its height).
        assert pixels[:, 1].max() - pixels[:, 1].min() > 0.5 * camera.height
    distances = (centers - target).norm(dim=-1)
    assert bool(((distances - 0.6).abs() < 0.06).all())
    # Spread over the sphere: the mean viewing direction nearly cancels out.
    assert ((centers - target) / distances[:, None]).mean(0).norm() < 0.1
    # Deterministic in the seed, different across seeds.
    again = make_rig(24, target)
    other = make_rig(24, target, seed=1)
    torch.testing.assert_close(torch.stack([c.t for c in again]), torch.stack([c.t for c in rig]))
    assert not torch.allclose(torch.stack([c.t for c in other]), torch.stack([c.t for c in rig]))


def test_make_rig_dome_leaves_out_the_bottom_cap():
    rig = make_rig(30, coverage=0.75, jitter=0.0)
    heights = torch.stack([camera.center for camera in rig])[:, 1] / 0.6
    # Heights are evenly spaced in [1 - 2 * 0.75, 1] = [-0.5, 1].
    assert heights.min() > -0.5 and heights.max() < 1.0


def test_json_round_trip(tmp_path):
    cameras = make_rig(3, radius=0.5)
    path = save_cameras(tmp_path / "cams" / "cameras.json", cameras)
    loaded = load_cameras(path)
    assert [c.name for c in loaded] == [c.name for c in cameras]
    for before, after in zip(cameras, loaded, strict=True):
        assert (after.width, after.height) == (before.width, before.height)
        for field in ("K", "R", "t"):
            torch.testing.assert_close(getattr(after, field), getattr(before, field))
    # float64 round trip is exact.
    camera64 = _simple_camera()
    save_cameras(tmp_path / "one.json", [camera64])
    (back,) = load_cameras(tmp_path / "one.json", dtype=torch.float64)
    assert torch.equal(back.R, camera64.R) and torch.equal(back.t, camera64.t)


def test_missing_field_names_file_and_field(tmp_path):
    data = [_simple_camera().to_dict()]
    del data[0]["t"]
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"broken\.json: camera 0: missing camera field\(s\): t"):
        load_cameras(path)


def test_invalid_fields_are_rejected(tmp_path):
    entry = _simple_camera().to_dict()
    entry["R"] = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]
    path = tmp_path / "bad_r.json"
    path.write_text(json.dumps([entry]))
    with pytest.raises(ValueError, match=r"bad_r\.json: camera 0: R must be a rotation"):
        load_cameras(path)
    entry = _simple_camera().to_dict()
    entry["width"] = 0
    with pytest.raises(ValueError, match="width"):
        Camera.from_dict(entry)
    entry = _simple_camera().to_dict()
    entry["K"] = [[1.0, 0.0], [0.0, 1.0]]
    with pytest.raises(ValueError, match=r"K must have shape \[3, 3\]"):
        Camera.from_dict(entry)
    path = tmp_path / "not_list.json"
    path.write_text(json.dumps({"K": 1}))
    with pytest.raises(ValueError, match=r"not_list\.json: expected a JSON list"):
        load_cameras(path)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_rays_on_cuda():
    camera = _simple_camera().to(device="cuda", dtype=torch.float32)
    origins, directions = pixel_rays(camera)
    assert origins.device.type == "cuda" and directions.device.type == "cuda"
    _, cpu_directions = pixel_rays(camera.to(device="cpu"))
    torch.testing.assert_close(directions.cpu(), cpu_directions, atol=1e-5, rtol=0)
