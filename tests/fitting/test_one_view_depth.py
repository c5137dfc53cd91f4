"""One calibrated view of the demo's second unseen hand (``lisa demo --seed 1``: synth seed 1001),
whose one-view keypoint fit stops 5 cm too near without the depth restarts
(``FitImagesConfig.depth_factors``). ``python -m benchmarks oneview`` measures the same over ten
such hands."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from lisa_hand.data.synth.dataset import SynthConfig, synthesize
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.keypoint_stage import fit_keypoints
from lisa_hand.fitting.images.views import read_views
from lisa_hand.fitting.stages import template_on
from lisa_hand.utils.threads import cpu_threads


@pytest.fixture(scope="module")
def second_hand(tmp_path_factory):
    root = tmp_path_factory.mktemp("oneview") / "hand1"
    with cpu_threads(1):
        synthesize(root, SynthConfig(num_subjects=1, num_poses=1, num_views=8,
                                     resolution=(384, 250), seed=1001),
                   progress=False, overwrite=True)
    return root / "s000" / "f000"


def _one_view_errors(frame, config) -> tuple[float, float]:
    """The keypoint stage on camera cam000 alone -> (MPJPE mm in world coordinates, no
    alignment; the fitted wrist's distance from the camera minus the true one, mm)."""
    views = read_views(frame, ["cam000"])
    template = template_on(None, torch.device("cpu"))
    with cpu_threads(1):
        hand, _ = fit_keypoints(views, config, template)
    with torch.no_grad():
        fitted = template.forward(hand.pose[None], hand.betas[None],
                                  hand.translation[None]).keypoints[0].double().numpy()
    truth = np.asarray(json.loads((frame / "params.json").read_text())["keypoints"], np.float64)
    camera = views[0].camera
    centre = -(camera.R.double().T @ camera.t.double()).numpy()
    depth = np.linalg.norm(fitted[0] - centre) - np.linalg.norm(truth[0] - centre)
    return (1000.0 * float(np.linalg.norm(fitted - truth, axis=-1).mean()),
            1000.0 * float(depth))


def test_depth_restarts_fix_the_second_demo_hand(second_hand):
    config = FitImagesConfig()
    error, depth = _one_view_errors(second_hand, config)
    before, before_depth = _one_view_errors(second_hand, replace(config, depth_factors=()))
    # Without the restarts: about 5 cm too near (51 mm MPJPE); with them: about 2 cm.
    assert before > 40.0 and before_depth < -40.0
    assert error < 25.0 and abs(depth) < 25.0
