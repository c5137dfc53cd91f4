"""The dataset readers on the tiny dataset: what they load, what they draw, and their errors."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import RayFrames, ScanFrames, read_frame_table
from lisa_hand.data.layout import read_image, read_mask, read_npz
from lisa_hand.geometry.cameras import load_cameras, pixel_rays

EXACT = "donot_use_mm_for_euclid_dist"


@pytest.fixture(scope="module")
def scans(tiny_data):
    return ScanFrames(tiny_data, "train")


@pytest.fixture(scope="module")
def rays(tiny_data):
    return RayFrames(tiny_data, "train", max_band_px=4, background_per_view=200)


def test_frame_table_reads_the_split(tiny_data):
    table = read_frame_table(tiny_data, "train")
    assert table.subject_ids == ["s000", "s001"]
    assert table.frame_keys == ["s000/f000", "s000/f001", "s001/f000", "s001/f001"]
    assert table.frame_subject.tolist() == [0, 0, 1, 1]
    params = json.loads((tiny_data / "s001/f001/params.json").read_text())
    assert torch.allclose(table.pose[3], torch.tensor(params["pose"], dtype=torch.float32))
    subject = json.loads((tiny_data / "s001/subject.json").read_text())
    assert torch.allclose(table.rest_joints[1],
                          torch.tensor(subject["template_rest_joints"], dtype=torch.float32))
    assert read_frame_table(tiny_data, "val").subject_ids == ["s002"]


def test_scan_sample_draws_points_of_the_chosen_frames(tiny_data, scans):
    generator = torch.Generator().manual_seed(0)
    batch = scans.sample(3, 50, 40, generator, near_fraction=0.25, margin=0.01)
    assert batch.surface_points.shape == (3, 50, 3)
    assert batch.surface_weights.shape == (3, 50, 16)
    assert batch.near_points.shape == (3, 10, 3) and batch.uniform_points.shape == (3, 30, 3)
    assert len(set(batch.frame_index.tolist())) == 3  # distinct frames
    for row, frame in enumerate(batch.frame_index.tolist()):
        arrays = read_npz(scans.table.frames[frame].scan)
        # Every drawn point is a point of that frame's scan, with its own normal and weights.
        dist = torch.cdist(batch.surface_points[row], torch.from_numpy(arrays["points"]),
                           compute_mode=EXACT)
        nearest = dist.argmin(dim=1)
        assert float(dist.min(dim=1).values.max()) == 0.0
        assert torch.equal(batch.surface_normals[row], torch.from_numpy(arrays["normals"])[nearest])
        weights = torch.from_numpy(arrays["template_weights"])[nearest]
        assert torch.allclose(batch.surface_weights[row], weights, atol=1e-3)
        near = torch.cdist(batch.near_points[row], torch.from_numpy(arrays["sdf_points"]),
                           compute_mode=EXACT)
        assert torch.equal(batch.near_sdf[row],
                           torch.from_numpy(arrays["sdf"])[near.argmin(dim=1)])
        low = arrays["points"].min(0) - 0.01
        high = arrays["points"].max(0) + 0.01
        uniform = batch.uniform_points[row].numpy()
        assert (uniform >= low - 1e-6).all() and (uniform <= high + 1e-6).all()
        assert batch.subject_index[row] == scans.table.frame_subject[frame]
        assert torch.equal(batch.pose[row], scans.table.pose[frame])
    again = scans.sample(3, 50, 40, torch.Generator().manual_seed(0), near_fraction=0.25,
                         margin=0.01)
    assert torch.equal(again.surface_points, batch.surface_points)
    assert torch.equal(again.uniform_points, batch.uniform_points)


def test_scan_sample_given_frames_and_more_frames_than_the_split(scans):
    generator = torch.Generator().manual_seed(1)
    batch = scans.sample(1, 4, 0, generator, frames=torch.tensor([2, 2, 0]))
    assert batch.frame_index.tolist() == [2, 2, 0]
    assert scans.sample(9, 4, 0, generator).frame_index.shape == (9,)
    with pytest.raises(ValueError, match="frames must be indices"):
        scans.sample(1, 4, 0, generator, frames=torch.tensor([4]))


def test_rays_match_the_images_masks_and_cameras(tiny_data, rays):
    assert rays.camera_names == ["cam000", "cam001", "cam002"]
    generator = torch.Generator().manual_seed(2)
    batch = rays.sample_rays(60, generator, 0.5, 2, num_frames=3)
    assert batch.origins.shape == (3, 20, 3) and batch.rgb.shape == (3, 20, 3)
    for row, frame in enumerate(batch.frame_index.tolist()):
        paths = rays.table.frames[frame]
        cameras = {camera.name: camera for camera in load_cameras(paths.cameras)}
        for ray in range(20):
            name = rays.camera_names[int(batch.camera_index[row, ray])]
            u, v = (batch.pixels[row, ray] - 0.5).long().tolist()
            image = read_image(paths.image(name))
            mask = read_mask(paths.mask(name))
            assert torch.allclose(batch.rgb[row, ray], torch.from_numpy(image[v, u]), atol=1e-6)
            assert bool(batch.in_mask[row, ray]) == bool(mask[v, u])
            origin, direction = pixel_rays(cameras[name], batch.pixels[row, ray][None])
            assert torch.allclose(batch.directions[row, ray], direction[0], atol=1e-6)
            assert torch.allclose(batch.origins[row, ray], origin[0], atol=1e-6)
            assert torch.equal(batch.rotations[row, ray], cameras[name].R.float())


def test_rays_mask_fraction_and_band(tiny_data, rays):
    from scipy.ndimage import distance_transform_edt

    generator = torch.Generator().manual_seed(3)
    inside = rays.sample_rays(64, generator, 1.0, 0, num_frames=4)
    assert bool(inside.in_mask.all())
    band = rays.sample_rays(64, generator, 1.0, 3, num_frames=4)
    outside = rays.sample_rays(64, generator, 0.0, 3, num_frames=4)
    assert not bool(outside.in_mask.any())
    for batch, in_band in ((band, True), (outside, False)):
        for row, frame in enumerate(batch.frame_index.tolist()):
            paths = rays.table.frames[frame]
            for ray in range(batch.rgb.shape[1]):
                name = rays.camera_names[int(batch.camera_index[row, ray])]
                u, v = (batch.pixels[row, ray] - 0.5).long().tolist()
                distance = np.ceil(distance_transform_edt(~read_mask(paths.mask(name))))[v, u]
                assert (distance <= 3) == in_band
    half = rays.sample_rays(40, generator, 0.5, 0, num_frames=1)
    assert int(half.in_mask.sum()) == 20  # the first half of each frame's rays


def test_missing_and_malformed_datasets_name_the_file(tiny_data, tmp_path):
    with pytest.raises(FileNotFoundError, match="no such dataset folder"):
        ScanFrames(tmp_path / "nothing")
    broken = tmp_path / "broken"
    shutil.copytree(tiny_data, broken)
    (broken / "split.json").write_text("{not json")
    with pytest.raises(ValueError, match="split.json: not valid JSON"):
        ScanFrames(broken)
    shutil.copy(tiny_data / "split.json", broken / "split.json")
    scan = broken / "s000/f001/scan.npz"
    arrays = read_npz(scan)
    arrays["normals"] = arrays["normals"][:5]
    np.savez(scan, **arrays)
    with pytest.raises(ValueError, match=r"s000/f001/scan.npz: 'normals' must have shape"):
        ScanFrames(broken)
    (broken / "s001/f000/masks/cam001.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"s001/f000/masks/cam001.png: no such file"):
        RayFrames(broken)
    params = broken / "s000/f000/params.json"
    params.write_text(json.dumps({"pose": [0.0] * 47, "translation": [0, 0, 0]}))
    with pytest.raises(ValueError, match=r"s000/f000/params.json: 'pose' must be finite"):
        read_frame_table(broken)
    with pytest.raises(ValueError, match="split must be one of"):
        read_frame_table(tiny_data, "training")
    with pytest.raises(ValueError, match="band_px must be an int in"):
        RayFrames(tiny_data, max_band_px=2).sample_rays(8, torch.Generator(), 0.5, 3)
