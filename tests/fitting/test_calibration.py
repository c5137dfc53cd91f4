"""The input views' colour response fitted beside the colour code (issue 15): the arithmetic of
:class:`ViewCalibration`, and on the tiny scene, views whose cameras have their own gains and
biases: without it the colour code absorbs them, with it the code stays near the truth and the
responses are recovered."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lisa_hand.fitting.images.calibration import ViewCalibration
from lisa_hand.fitting.images.color_stage import fit_color
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.folder import render_fitted_views
from tests.fitting.image_scene import FAST_RENDER, load_float_template, make_scene

# Relative responses of the scene's 3 views: zero mean over the views, so that no colour code
# can explain them, within 1-2 standard deviations of the default spread (0.087, 0.029).
RELATIVE_GAINS = torch.tensor([[1.12, 0.90, 1.00], [0.90, 1.00, 1.12], [0.98, 1.10, 0.88]])
RELATIVE_BIASES = torch.tensor([[0.04, -0.03, 0.0], [-0.03, 0.0, 0.04], [-0.01, 0.03, -0.04]])


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


def test_gains_biases_prior_and_dict_by_hand():
    calibration = ViewCalibration(2, gain_std=0.1, bias_std=0.02, enabled=True,
                                  device=torch.device("cpu"))
    gain, bias = torch.tensor([1.0, 2.0, 0.5]), torch.tensor([0.1, 0.0, -0.1])
    gains, biases = calibration.gains_biases(gain, bias)
    assert torch.equal(gains, gain.expand(2, 3)) and torch.equal(biases, bias.expand(2, 3))
    with torch.no_grad():
        calibration.z_gain[1] = torch.tensor([1.0, -2.0, 0.0])
        calibration.z_bias[0] = torch.tensor([0.0, 0.0, 3.0])
    gains, biases = calibration.gains_biases(gain, bias)
    assert torch.allclose(gains[1], torch.tensor([1.1, 1.6, 0.5]))
    assert torch.allclose(biases[0], torch.tensor([0.1, 0.0, -0.04]))
    per_ray_gain, per_ray_bias = calibration.for_rays(gain, bias, torch.tensor([1, 0, 1]))
    assert torch.equal(per_ray_gain[0], gains[1]) and torch.equal(per_ray_bias[1], biases[0])
    # 0.5 * mean over the 2 views of |z|^2: view 0: 9, view 1: 1 + 4 -> 0.5 * 7
    assert float(calibration.prior().detach()) == pytest.approx(3.5)
    table = calibration.to_dict(["a", "b"], gain, bias)
    assert table["b"]["gain"] == pytest.approx([1.1, 1.6, 0.5])
    assert table["a"]["bias"] == pytest.approx([0.1, 0.0, -0.04])
    assert len(calibration.parameters()) == 2


def test_disabled_calibration_is_the_mean_one():
    for calibration in (ViewCalibration(3, 0.1, 0.02, False, torch.device("cpu")),
                        ViewCalibration(3, 0.0, 0.0, True, torch.device("cpu"))):
        assert not calibration.enabled and calibration.parameters() == []
        assert float(calibration.prior()) == 0.0
        gains, _ = calibration.gains_biases(torch.ones(3), torch.zeros(3))
        assert torch.equal(gains, torch.ones(3, 3))
    with pytest.raises(ValueError, match="num_views must be >= 1"):
        ViewCalibration(0, 0.1, 0.02, True, torch.device("cpu"))
    with pytest.raises(ValueError, match="gain_std must be >= 0"):
        ViewCalibration(1, -0.1, 0.02, True, torch.device("cpu"))


def test_config_checks_the_calibration_settings():
    with pytest.raises(ValueError, match="view_calibration_lr must be > 0"):
        FitImagesConfig(view_calibration_lr=0.0)
    with pytest.raises(ValueError, match="view_bias_std must be >= 0"):
        FitImagesConfig(view_bias_std=-1.0)
    with pytest.raises(TypeError, match="view_calibration must be True or False"):
        FitImagesConfig(view_calibration=1)


@pytest.fixture(scope="module")
def responded(tmp_path_factory):
    """The tiny scene with each view seen through its own camera response (the images
    ``g_v * c + b_v * opacity`` of the model's calibrated colour ``c``)."""
    scene = make_scene(tmp_path_factory)
    renders = render_fitted_views(scene["model"], scene["truth"], scene["views"], samples=24)
    views = []
    for index, (view, render) in enumerate(zip(scene["views"], renders, strict=True)):
        rgb = (RELATIVE_GAINS[index] * render.rgb
               + RELATIVE_BIASES[index] * render.opacity[..., None]).clamp(0.0, 1.0)
        views.append(dataclasses.replace(view, rgb=rgb))
    return scene, views


def test_fitted_responses_keep_the_colour_code(responded):
    scene, views = responded
    model, truth = scene["model"], scene["truth"]
    config = FitImagesConfig(color_iters=60, num_rays=512, render=FAST_RENDER, code_lr=0.05,
                             shape_fit="fixed", view_calibration_lr=0.1)
    template = load_float_template()
    with_calibration, report = fit_color(model, views, truth, config, template)
    without, _ = fit_color(model, views, truth,
                           dataclasses.replace(config, view_calibration=False), template)
    # Both start at the true codes: the views' responses pull the code away, less with the
    # responses fitted (measured: 0.76 and 2.02).
    error_with = float((with_calibration.color_code - truth.color_code).norm())
    error_without = float((without.color_code - truth.color_code).norm())
    assert error_with < 0.6 * error_without
    assert "view_calibration" not in without.extra
    table = with_calibration.extra["view_calibration"]
    assert list(table) == [view.name for view in views]
    # The relative gains recovered: their deviations from the mean correlate with the truth
    # (measured: 0.999).
    fitted = torch.tensor([table[view.name]["gain"] for view in views]) / model.gain
    truth_dev = (RELATIVE_GAINS - RELATIVE_GAINS.mean(0)).reshape(-1)
    fitted_dev = (fitted - fitted.mean(0)).reshape(-1)
    correlation = float(torch.corrcoef(torch.stack([truth_dev, fitted_dev]))[0, 1])
    assert correlation > 0.7
    assert "calibration" in report.history[-1]


def test_one_view_keeps_the_mean_calibration(responded):
    scene, views = responded
    config = FitImagesConfig(color_iters=2, num_rays=64, render=FAST_RENDER, shape_fit="fixed")
    template = load_float_template()
    one, report = fit_color(scene["model"], views[:1], scene["truth"], config, template)
    assert "view_calibration" not in one.extra and report.history[-1]["calibration"] == 0.0
    two, _ = fit_color(scene["model"], views[:2], scene["truth"], config, template)
    assert list(two.extra["view_calibration"]) == [view.name for view in views[:2]]
    with pytest.raises(ValueError, match="view_calibration_min_views must be an int >= 1"):
        FitImagesConfig(view_calibration_min_views=0)
