"""Orbit cameras and turntable GIFs."""

import math

import numpy as np
import pytest
import torch

from lisa_hand.render.image import ImageRenderConfig
from lisa_hand.render.turntable import (
    mp4_backend,
    orbit_cameras,
    render_turntable,
    save_gif,
    save_video,
)

from .image_scene import SMALL_GRID, sphere_sdf, textured_field


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
    if mp4_backend() is None:
        with pytest.raises(OSError, match="imageio-ffmpeg"):
            save_video(tmp_path / "turn.mp4", frames)
        assert not (tmp_path / "turn.mp4").exists()
