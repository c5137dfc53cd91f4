"""Shared fixtures of the training tests: the tiny dataset (written once per session) and tiny
configurations of the two trainers."""

from __future__ import annotations

import pytest

from lisa_hand.fields.config import FieldConfig
from lisa_hand.render import RenderConfig
from lisa_hand.training.config import TrainerConfig
from lisa_hand.training.images import ImageTrainConfig
from lisa_hand.training.prior import PriorConfig
from lisa_hand.utils.threads import cpu_threads

from .tiny_dataset import write_tiny_dataset

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8)


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory):
    """A dataset of 3 subjects (s000, s001 train; s002 val) x 2 frames x 3 views of 64 x 48."""
    with cpu_threads(1):  # the CPU is shared: one thread per test process
        return write_tiny_dataset(tmp_path_factory.mktemp("tiny") / "data")


@pytest.fixture(autouse=True)
def _one_thread_per_training_test():
    """Every training test on one torch thread (restored after it): the CPU is shared with the
    test's subprocesses."""
    with cpu_threads(1):
        yield


def tiny_trainer(**kwargs) -> TrainerConfig:
    base = dict(steps=20, lr=2e-3, device="cpu", progress=False, print_every=0,
                checkpoint_every=0, seed=3, grad_sync="allreduce")
    base.update(kwargs)
    return TrainerConfig(**base)


def tiny_prior_config(**kwargs) -> PriorConfig:
    base = dict(field=FieldConfig(use_color=False, **TINY_FIELD), trainer=tiny_trainer(),
                frames_per_step=2, surface_points=96, space_points=96)
    base.update(kwargs)
    return PriorConfig(**base)


def tiny_image_config(**kwargs) -> ImageTrainConfig:
    base = dict(field=FieldConfig(**TINY_FIELD), trainer=tiny_trainer(),
                render=RenderConfig(sampler="uniform", num_samples=24, stratified=True),
                num_rays=96, num_frames=2, eikonal_ray_points=16, eikonal_uniform_points=16,
                skinning_points=32, band_px=2, max_band_px=4, background_per_view=256,
                beta_init=0.004)
    base.update(kwargs)
    return ImageTrainConfig(**base)
