"""The render benchmark's plumbing: a small render of each kind of scene, the device it names,
and the scenes a GPU cannot render."""

from __future__ import annotations

import pytest
import torch

from lisa_hand.bench._scenes import make_scene
from lisa_hand.bench.render import run_render_benchmark
from lisa_hand.utils.threads import cpu_threads


def test_small_capsule_render_matches_its_reference():
    with cpu_threads(1):
        result = run_render_benchmark("capsules", 64, 42, dense_pixels=50, log=lambda line: None)
    assert result["device"] == "cpu" and result["resolution"] == "64x42"
    assert result["mask_pixels"] > 100 and result["rays_rendered"] <= result["rays_in_bound"]
    # An exact SDF: the fast path is the reference image to within sampling noise.
    assert result["psnr_vs_reference_hand_db"] > 30.0
    assert result["dense_check"]["psnr_fast_db"] > 30.0


def test_analytic_scenes_refuse_a_gpu():
    with pytest.raises(ValueError, match="renders on the CPU only"):
        make_scene("capsules", 32, 21, device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_trained_render_on_cuda_matches_the_cpu():
    results = {}
    for device in ("cpu", "cuda"):
        results[device] = run_render_benchmark("trained", 96, 63, dense_pixels=0,
                                               save_dir=None, device=device,
                                               log=lambda line: None)
    assert results["cuda"]["device"].startswith("cuda")
    assert results["cuda"]["mask_pixels"] == pytest.approx(results["cpu"]["mask_pixels"], rel=0.02)
    assert results["cuda"]["psnr_vs_reference_hand_db"] > 35.0
