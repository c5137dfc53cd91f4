"""Streaming readers (DataLoader workers, DistributedSampler shares, hand crops, a bounded
buffer) against the in-memory ones on an imported InterHand2.6M-format split."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import RayFrames, ScanFrames
from lisa_hand.data.importers.interhand import InterHandConfig, import_interhand
from lisa_hand.data.layout import read_image, read_mask
from lisa_hand.geometry.cameras import load_cameras, pixel_rays
from lisa_hand.training.streaming import (
    FrameBuffer,
    StreamingRayFrames,
    StreamingScanFrames,
    frame_loader,
)
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
    stream = StreamingRayFrames(data, "train", background_per_view=64, workers=2)
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
            assert torch.equal(batch.rotations[row, k], cameras[name].R.float())


def test_deterministic_whatever_the_workers(data):
    def draw(workers):
        stream = StreamingRayFrames(data, "train", background_per_view=32, cache_frames=4,
                                    workers=workers, seed=5)
        generator = torch.Generator().manual_seed(3)
        batches = [stream.sample_rays(64, generator, num_frames=2) for _ in range(6)]
        stream.close()
        return batches

    in_process = draw(0)
    for first, second, third in zip(in_process, draw(0), draw(2), strict=True):
        for other in (second, third):
            assert torch.equal(first.frame_index, other.frame_index)
            assert torch.equal(first.rgb, other.rgb) and torch.equal(first.pixels, other.pixels)
    drawn = torch.cat([batch.frame_index for batch in in_process]).tolist()
    assert len(set(drawn)) > 4  # the buffer of 4 is refilled from the loader


def _frames(loader) -> list[int]:
    return [item.frame for item in loader]


def test_loader_workers_yield_the_same_frames(data):
    stream = StreamingRayFrames(data, "train", background_per_view=16)
    dataset = stream.dataset
    epochs = []
    for epoch in (0, 1):
        in_process = list(frame_loader(dataset, workers=0, seed=2, epoch=epoch))
        workers = list(frame_loader(dataset, workers=2, seed=2, epoch=epoch))
        assert sorted(_frames(in_process)) == list(range(stream.num_frames))
        assert _frames(in_process) == _frames(workers)  # same order, not only the same set
        for a, b in zip(in_process, workers, strict=True):
            assert np.array_equal(a.near_pixel, b.near_pixel)
            assert np.array_equal(a.far_rgb, b.far_rgb)
        epochs.append(_frames(in_process))
    assert epochs[0] != epochs[1]  # a new shuffle each epoch


def test_two_ranks_read_disjoint_shares(data):
    stream = StreamingRayFrames(data, "train", background_per_view=16)
    num_frames = stream.num_frames
    share = -(-num_frames // 2)
    for epoch in (0, 3):
        ranks = [_frames(frame_loader(stream.dataset, seed=7, epoch=epoch, num_replicas=2,
                                      rank=rank)) for rank in (0, 1)]
        assert [len(r) for r in ranks] == [share, share]
        assert set(ranks[0]) | set(ranks[1]) == set(range(num_frames))
        # disjoint but for the sampler's padding (2 * share - num_frames repeated frames)
        assert len(set(ranks[0]) & set(ranks[1])) <= 2 * share - num_frames
    # a streaming reader of rank 1 only ever loads its share of the current epoch
    reader = StreamingRayFrames(data, "train", background_per_view=16, cache_frames=3,
                                num_replicas=2, rank=1, seed=7)
    mine = set(_frames(frame_loader(reader.dataset, seed=7, num_replicas=2, rank=1)))
    generator = torch.Generator().manual_seed(0)
    for _ in range(2):
        batch = reader.sample_rays(16, generator, num_frames=2)
        # rank 1 trains on row 1 (shard_slice); both rows are frames of its share
        assert set(batch.frame_index.tolist()) <= mine
    assert reader.buffer.epoch == 0 and reader.buffer.loaded == 3 + 2  # one row consumed a step


def test_every_frame_once_per_epoch(data):
    """Each row of a step is uniform over the split, and the split is covered evenly: over 10
    epochs every frame is loaded 10 or 11 times, and drawn as often but for the 3 frames left in
    the buffer (8 to 11 times; i.i.d. draws spread the counts by about +-3: all 9 in [8, 11]
    has a chance under 1%)."""
    scans = StreamingScanFrames(data, "train", cache_frames=3, seed=1)
    generator = torch.Generator().manual_seed(2)
    steps = 5 * scans.num_frames  # 2 frames a step: 10 epochs
    drawn = torch.cat([scans.sample(2, 4, 0, generator, near_fraction=0.0).frame_index
                       for _ in range(steps)])
    counts = torch.bincount(drawn, minlength=scans.num_frames)
    assert int(counts.sum()) == 2 * steps and 8 <= int(counts.min()) <= int(counts.max()) <= 11


def test_crop_keeps_every_mask_pixel(data):
    stream = StreamingRayFrames(data, "train", background_per_view=16, max_band_px=3)
    for frame in range(stream.num_frames):
        pool = stream.dataset[frame]
        paths = stream.table.frames[frame]
        for local, (name, width, height) in enumerate(stream.dataset.views[frame]):
            mask = read_mask(paths.mask(name))
            r0, r1, c0, c1 = pool.crop[local].tolist()
            rows, cols = np.nonzero(mask)
            assert rows.size > 0 and (r1 - r0) * (c1 - c0) < width * height  # a real crop
            assert r0 <= rows.min() and rows.max() < r1 and c0 <= cols.min() and cols.max() < c1
            here = pool.near_view == local
            inside = pool.near_pixel[here & (pool.near_distance == 0)]
            assert np.array_equal(np.sort(inside), np.flatnonzero(mask.reshape(-1)))
            near = pool.near_pixel[here]
            assert np.all((near // width >= r0) & (near // width < r1))
            assert not np.isin(pool.far_pixel[pool.far_view == local], near).any()


def test_memory_stays_bounded(data):
    stream = StreamingRayFrames(data, "train", background_per_view=8, cache_frames=3)
    generator = torch.Generator().manual_seed(1)
    drawn = []
    for _ in range(12):
        drawn.append(stream.sample_rays(8, generator, num_frames=2).frame_index.tolist())
        assert len(stream.buffer.slots) <= 3
    assert stream.buffer.loaded == 3 + 2 * 12 and stream.buffer.epoch >= 2
    first = [f for step in drawn[:2] for f in step]
    assert len(set(first)) == 4  # consumed frames come back only in a later epoch
    for _ in range(3):
        stream.sample_rays(4 * stream.num_frames, generator, frames=torch.arange(stream.num_frames))
    assert len(stream._cache) <= 3
    scans = StreamingScanFrames(data, "train", cache_frames=2, seed=4)
    for _ in range(5):
        scans.sample(2, 10, 0, generator, near_fraction=0.0)
        assert len(scans.buffer.slots) <= 2
    with pytest.raises(ValueError, match="buffer size"):
        FrameBuffer(stream.dataset, 0)
    with pytest.raises(ValueError, match="workers"):
        FrameBuffer(stream.dataset, 2, workers=-1)


def test_streaming_scans_give_the_file_rows(data):
    stream = StreamingScanFrames(data, "train", cache_frames=2, workers=1)
    memory = ScanFrames(data, "train")
    generator = torch.Generator().manual_seed(0)
    batch = stream.sample(3, 50, 20, generator, near_fraction=0.0)  # 3 > 2 cached: repeats
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
    assert rays.buffer.workers == config.stream_workers == 2
    with pytest.raises(ValueError, match="stream_cache"):
        tiny_image_config(stream=True, stream_cache=1)
    with pytest.raises(ValueError, match="stream_workers"):
        tiny_prior_config(stream_workers=-1)
    result = train_images(data, tmp_path / "run", config)
    assert result.status == "completed" and (tmp_path / "run" / "last.pt").is_file()
    prior = train_prior(data, tmp_path / "prior", tiny_prior_config(
        trainer=tiny_trainer(steps=2), stream=True, near_fraction=0.0))
    assert prior.status == "completed"
