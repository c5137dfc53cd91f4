"""Streaming readers against the in-memory ones on an imported InterHand2.6M-format split."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import RayFrames, ScanFrames
from lisa_hand.data.importers.interhand import InterHandConfig, import_interhand
from lisa_hand.data.layout import read_image, read_mask
from lisa_hand.geometry.cameras import load_cameras, pixel_rays
from lisa_hand.training.streaming import StreamingRayFrames, StreamingScanFrames
from tests.data.importers.fixtures import interhand_fixture


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("stream")
    interhand_fixture(root / "ih", masks=True)
    import_interhand(InterHandConfig(root=str(root / "ih"), masks=str(root / "ih" / "masks"),
                                     skinning_points=300), root / "DATA", progress=False)
    return root / "DATA"


def test_same_split_as_the_in_memory_reader(data):
    stream = StreamingRayFrames(data, "train", background_per_view=64)
    memory = RayFrames(data, "train", background_per_view=64)
    assert stream.num_frames == memory.num_frames
    assert stream.camera_names == memory.camera_names
    assert stream.subject_ids == memory.subject_ids
    assert stream.table.frame_keys == memory.table.frame_keys


def test_rays_hit_the_right_pixels(data):
    stream = StreamingRayFrames(data, "train", background_per_view=64, threads=2)
    batch = stream.sample_rays(512, torch.Generator().manual_seed(0), 0.75, 4, num_frames=4)
    assert batch.origins.shape == (4, 128, 3) and batch.rgb.shape == (4, 128, 3)
    assert 0.3 < float(batch.in_mask.float().mean()) < 0.95
    for row in range(4):
        paths = stream.table.frames[int(batch.frame_index[row])]
        cameras = {c.name: c for c in load_cameras(paths.cameras)}
        for k in range(0, 128, 9):
            name = stream.camera_names[int(batch.camera_index[row, k])]
            u, v = (batch.pixels[row, k] - 0.5).long().tolist()
            image = read_image(paths.image(name))
            assert torch.allclose(batch.rgb[row, k], torch.from_numpy(image[v, u]), atol=1 / 255)
            assert bool(batch.in_mask[row, k]) == bool(read_mask(paths.mask(name))[v, u])
            origin, direction = pixel_rays(cameras[name], batch.pixels[row, k][None])
            assert torch.allclose(batch.directions[row, k], direction[0], atol=1e-5)
            assert torch.allclose(batch.origins[row, k], origin[0], atol=1e-5)


def test_deterministic_whatever_the_cache(data):
    def draw(cache):
        stream = StreamingRayFrames(data, "train", background_per_view=32, cache_frames=cache,
                                    threads=1)
        generator = torch.Generator().manual_seed(3)
        batches = [stream.sample_rays(64, generator, num_frames=2) for _ in range(4)]
        assert len(stream._cache) <= cache
        return batches

    for first, second in zip(draw(1), draw(16), strict=True):
        assert torch.equal(first.frame_index, second.frame_index)
        assert torch.equal(first.rgb, second.rgb) and torch.equal(first.pixels, second.pixels)


def test_streaming_scans_give_the_file_rows(data):
    stream = StreamingScanFrames(data, "train", cache_frames=2)
    memory = ScanFrames(data, "train")
    generator = torch.Generator().manual_seed(0)
    batch = stream.sample(3, 50, 20, generator, near_fraction=0.0)
    assert batch.surface_points.shape == (3, 50, 3) and batch.uniform_points.shape == (3, 20, 3)
    for row, frame in enumerate(batch.frame_index.tolist()):
        start, count = int(memory.surface_start[frame]), int(memory.surface_count[frame])
        points = memory.surface_points[start:start + count]
        distance = torch.cdist(batch.surface_points[row], points,
                               compute_mode="donot_use_mm_for_euclid_dist").min(dim=1).values
        assert float(distance.max()) < 1e-6  # every drawn point is a point of that frame
    with pytest.raises(ValueError, match="near_fraction=0"):
        stream.sample(1, 5, 10, generator, near_fraction=0.5)


def test_bad_arguments(data):
    stream = StreamingRayFrames(data, "train", background_per_view=8)
    with pytest.raises(ValueError, match="multiple"):
        stream.sample_rays(7, torch.Generator(), num_frames=2)
    with pytest.raises(ValueError, match="band_px"):
        stream.sample_rays(8, torch.Generator(), band_px=99)
    assert np.isfinite(stream.view_world_from_pixel.numpy()).all()


def test_training_streams_an_imported_split(data, tmp_path):
    """lisa train with --set stream=true on the imported InterHand2.6M-format split, and
    lisa train-prior streaming the tiny dataset's scans: both run and checkpoint."""
    from lisa_hand.training.images import load_image_data, train_images
    from lisa_hand.training.prior import train_prior

    from .conftest import tiny_image_config, tiny_prior_config, tiny_trainer

    config = tiny_image_config(trainer=tiny_trainer(steps=3), stream=True)
    rays, scans = load_image_data(data, config)
    assert isinstance(rays, StreamingRayFrames) and isinstance(scans, StreamingScanFrames)
    result = train_images(data, tmp_path / "run", config)
    assert result.status == "completed" and (tmp_path / "run" / "last.pt").is_file()
    prior = train_prior(data, tmp_path / "prior", tiny_prior_config(
        trainer=tiny_trainer(steps=2), stream=True, near_fraction=0.0))
    assert prior.status == "completed"
