"""The global-pose search of the image fit: the closed-form translation and the triangulation
are exact on noiseless keypoints; the candidate rotations are distinct."""

from __future__ import annotations

import math

import pytest
import torch

from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.pose_search import (
    random_rotations,
    rotation_angles,
    solve_translation,
    triangulate,
    view_candidate_rotations,
)
from lisa_hand.fitting.images.terms import ViewData
from lisa_hand.fitting.priors import prior_mean_fingers
from lisa_hand.geometry import axis_angle_to_matrix
from tests.fitting.image_scene import load_float_template, make_scene

pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory)


def test_translation_and_triangulation_are_exact_on_noiseless_keypoints(scene):
    views = scene["views"]
    config = FitImagesConfig()
    data = ViewData(views, config.coverage_pixels, torch.Generator().manual_seed(0))
    template = load_float_template()
    truth = scene["truth"]
    posed = template.forward(truth.pose[None], truth.betas[None], None)
    shift = solve_translation(posed.keypoints, data)
    assert torch.allclose(shift[0], truth.translation, atol=2e-5)
    shift = solve_translation(posed.keypoints, data, palm_only=True)
    assert torch.allclose(shift[0], truth.translation, atol=2e-5)
    points, valid = triangulate(data)
    assert bool(valid.all())
    expected = posed.keypoints[0] + truth.translation
    assert (points - expected).abs().max() < 1e-4  # metres


def test_view_candidate_rotations_are_apart_and_the_first_is_close(scene):
    config = FitImagesConfig(rotation_pool=256, restarts=5)
    data = ViewData(scene["views"], config.coverage_pixels, torch.Generator().manual_seed(0))
    rotations = view_candidate_rotations(load_float_template(), data, config,
                                         prior_mean_fingers("relaxed"), torch.Generator())
    assert rotations.shape == (5, 3)
    matrices = axis_angle_to_matrix(rotations)
    angles = rotation_angles(matrices, matrices)
    off_diagonal = angles[~torch.eye(5, dtype=torch.bool)]
    assert bool((off_diagonal >= math.radians(config.restart_separation_deg) - 1e-4).all())
    truth = axis_angle_to_matrix(scene["truth"].pose[:3])[None]
    assert float(rotation_angles(matrices[:1], truth)) < math.radians(30.0)
    uniform = axis_angle_to_matrix(random_rotations(2000, torch.Generator().manual_seed(1)))
    assert abs(float(uniform.mean(0).abs().max())) < 0.05  # uniform: the mean matrix is ~0
