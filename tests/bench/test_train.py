"""The image-training benchmark's parts: the held-out copy of a dataset, the prior taken from a
trained model, the two configurations, and PSNR of a run's held-out views."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.bench.field import BENCH_REST_JOINTS
from lisa_hand.bench.train import (
    evaluate,
    fast_config,
    held_out_copy,
    measure_rates,
    prior_from_trained,
    reference_config,
    run_variant,
)
from lisa_hand.data.datasets import RayFrames
from lisa_hand.geometry.cameras import load_cameras
from lisa_hand.model.trained import load_trained
from lisa_hand.training.images import train_images
from tests.training.conftest import tiny_image_config, tiny_trainer
from tests.training.tiny_dataset import write_tiny_dataset


def test_held_out_copy_drops_one_camera_and_trains(tmp_path):
    data = write_tiny_dataset(tmp_path / "data")
    names = [c.name for c in load_cameras(next(data.glob("s*/f*/cameras.json")))]
    copy = held_out_copy(data, tmp_path / "copy", names[-1])
    frames = sorted(copy.glob("s*/f*/cameras.json"))
    assert len(frames) == len(list(data.glob("s*/f*/cameras.json")))
    for cameras_file in frames:
        assert [c.name for c in load_cameras(cameras_file)] == names[:-1]
    rays = RayFrames(copy, "train", max_band_px=2, background_per_view=16)
    assert rays.camera_names == sorted(names[:-1])
    # A run on the copy, scored on the camera it never saw.
    run = tmp_path / "run"
    train_images(copy, run, tiny_image_config(trainer=tiny_trainer(steps=2)))
    scores = evaluate(run, data, names[-1], scale=1.0)
    assert scores["frames"] == RayFrames(data, "train", max_band_px=0,
                                         background_per_view=0).num_frames
    assert 3.0 < scores["psnr_image"] < 60.0 and 0.0 < scores["psnr_mask"] < 60.0
    # The geometry figure: mean |SDF| at the true surface points, against the field evaluated
    # directly (LisaModel.forward, not the inference HandField the bench uses).
    trained = load_trained(run)
    table = RayFrames(data, "train", max_band_px=0, background_per_view=0).table
    errors = []
    for frame, paths in enumerate(table.frames):
        subject = int(table.frame_subject[frame])
        row = trained.subject_ids.index(table.subject_ids[subject])
        points = torch.as_tensor(np.load(paths.scan)["points"][:4000], dtype=torch.float32)
        with torch.no_grad():
            sdf = trained.field.float()(
                points[None], table.pose[frame][None].float(),
                table.translation[frame][None].float(),
                table.rest_joints[subject][None].float(), trained.shape_codes[row][None].float(),
                trained.color_codes[row][None].float()).sdf
        errors.append(1000.0 * float(sdf.abs().mean()))
    assert 0.0 < scores["surface_error_mm"] < 100.0
    assert abs(scores["surface_error_mm"] - float(np.mean(errors))) < 1e-3


def test_prior_from_the_shipped_model_has_its_geometry():
    trained = load_trained()
    prior = prior_from_trained()
    assert prior.field.color_mlp is None and prior.subject_ids == ["mean"]
    code = trained.shape_codes.float().mean(dim=0)
    torch.testing.assert_close(prior.shape_codes.weight[0], code)
    points = 0.03 * torch.randn(1, 64, 3, generator=torch.Generator().manual_seed(0))
    pose = torch.zeros(1, 48)
    rest = torch.tensor(BENCH_REST_JOINTS)[None]
    with torch.no_grad():
        ours = prior.field(points, pose, None, rest, code[None]).sdf
        colour = trained.color_codes.float().mean(dim=0)[None]
        theirs = trained.field.float()(points, pose, None, rest, code[None], colour).sdf
    torch.testing.assert_close(ours, theirs, rtol=0, atol=1e-6)


def test_reference_and_fast_configurations_differ_only_in_the_step():
    ref, fast = reference_config(10), fast_config(10)
    assert not ref.batched_step and fast.batched_step
    assert ref.render.samples_per_ray == 64 and fast.render.samples_per_ray == 16
    assert (ref.eikonal_ray_points, ref.skinning_points) == (256, 512)
    for name in ("num_rays", "num_frames", "lambda_col", "lambda_eik", "lambda_w", "field"):
        assert getattr(ref, name) == getattr(fast, name), name
    assert ref.trainer == fast.trainer


def test_one_variant_run_trains_with_its_overrides(tmp_path):
    # --steps N --set ...: the fast step with the overrides, trained and scored like the others.
    import json

    data = write_tiny_dataset(tmp_path / "data")
    names = [c.name for c in load_cameras(next(data.glob("s*/f*/cameras.json")))]
    copy = held_out_copy(data, tmp_path / "copy", names[-1])
    result = run_variant(copy, data, tmp_path, names[-1], None, 2,
                         ["lambda_surface=100", "render.num_samples=6"], 1.0)
    run = tmp_path / "run_lambda_surface-100_rendernum_samples-6"
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert len(log) == 2 and "surf" in log[0]["losses"]
    config = json.loads((run / "config.json").read_text())
    assert config["lambda_surface"] == 100.0 and config["render"]["num_samples"] == 6
    assert result["steps"] == 2 and result["overrides"] == ["lambda_surface=100",
                                                            "render.num_samples=6"]
    assert 0.0 < result["surface_error_mm"] < 100.0 and result["frames"] == 4


@pytest.mark.parametrize("device", [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(),
                                                  reason="needs CUDA")),
])
def test_step_rates_of_both_configurations(tmp_path, device):
    data = write_tiny_dataset(tmp_path / "data")
    names = [c.name for c in load_cameras(next(data.glob("s*/f*/cameras.json")))]
    copy = held_out_copy(data, tmp_path / "copy", names[-1])
    rates = measure_rates(copy, None, rounds=1, steps=2, device=device)
    assert set(rates) == {"reference", "fast"}
    assert all(0.0 < seconds < 60.0 for seconds in rates.values())


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without CUDA")
def test_step_rates_on_a_missing_gpu_say_so(tmp_path):
    with pytest.raises(ValueError, match="CUDA is not available"):
        measure_rates(tmp_path, None, rounds=1, steps=1, device="cuda")
