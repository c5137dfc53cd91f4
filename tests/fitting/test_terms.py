"""Energy terms as objects (``lisa_hand.fitting.terms``): each term against its formula, the
sum skipping what does not apply, and the one prior of the point and image fitters against
the formulas written out."""

from __future__ import annotations

import pytest
import torch

from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.points.config import FitPointsConfig
from lisa_hand.fitting.priors import (
    finger_coupling,
    finger_pose_prior,
    joint_limit_excess,
    prior_mean_fingers,
    thumb_pose_prior,
)
from lisa_hand.fitting.terms import (
    BetasPrior,
    Energy,
    HandTerms,
    JointLimits,
    ShapeCodePrior,
    hand_prior,
)


def _hands(count: int = 3) -> HandTerms:
    generator = torch.Generator().manual_seed(0)
    return HandTerms(pose=torch.randn(count, 45, generator=generator) * 0.6,
                     shape_code=torch.randn(count, 8, generator=generator) * 0.02,
                     betas=torch.randn(count, 10, generator=generator))


def test_each_term_is_its_formula():
    hands = _hands()
    assert torch.allclose(ShapeCodePrior("shape", 1.0, 0.02).value(hands),
                          (hands.shape_code / 0.02).square().mean(-1))
    assert torch.allclose(BetasPrior("betas", 1.0).value(hands), hands.betas.square().mean(-1))
    assert ShapeCodePrior("shape", 1.0).value(HandTerms(pose=hands.pose)) is None
    assert float(JointLimits("limits", 1.0).value(hands).min()) > 0  # 0.6 rad noise: past them


def test_the_energy_sums_the_weighted_terms_that_apply():
    hands = HandTerms(pose=_hands().pose, betas=_hands().betas)  # no shape code
    energy = Energy((JointLimits("limits", 2.0), ShapeCodePrior("shape", 5.0, 0.1),
                     BetasPrior("betas", 0.0), BetasPrior("betas_again", 3.0)))
    parts = energy.parts(hands)
    assert list(parts) == ["limits", "betas_again"]  # shape: no input; betas: weight 0
    expected = 2.0 * joint_limit_excess(hands.pose) + 3.0 * hands.betas.square().mean(-1)
    assert torch.allclose(energy(hands), expected)
    assert torch.equal(Energy(()).__call__(hands), torch.zeros(3))


def test_the_point_fit_prior_is_its_formula():
    config = FitPointsConfig(coupling_weight=2e-4, unseen_thumb_weight=5e-4)
    hands = _hands()
    mean = prior_mean_fingers(config.prior_pose)
    coupling = torch.tensor([0.0, 0.5, 0.0, 1.0, 0.8])
    got = hand_prior(config, mean, shape_scale=0.02, coupling=coupling)(hands)
    expected = (config.pose_weight * finger_pose_prior(hands.pose, mean)
                + 2e-4 * finger_coupling(hands.pose, coupling[:4])
                + 5e-4 * 0.8 * thumb_pose_prior(hands.pose, mean)
                + config.limit_weight * joint_limit_excess(hands.pose)
                + config.shape_weight * (hands.shape_code / 0.02).square().mean(-1)
                + config.betas_weight * hands.betas.square().mean(-1))
    assert torch.allclose(got, expected, rtol=1e-6)


def test_the_image_fit_prior_is_its_formula():
    class Size:
        def energy(self, joints):
            return joints.square().sum((-1, -2))

    config = FitImagesConfig()
    hands = _hands()
    pose = torch.cat([torch.zeros(3, 3), hands.pose], -1)  # [K, 48]: the rotation is free
    joints = torch.randn(3, 16, 3, generator=torch.Generator().manual_seed(1))
    mean = prior_mean_fingers(config.prior_pose)
    got = hand_prior(config, mean, size_prior=Size())(
        HandTerms(pose=pose, betas=hands.betas, joints=joints))
    expected = (config.pose_weight * finger_pose_prior(pose, mean)
                + config.betas_weight * hands.betas.square().mean(-1)
                + config.size_weight * joints.square().sum((-1, -2))
                + config.limit_weight * joint_limit_excess(pose))
    assert torch.allclose(got, expected, rtol=1e-6)
    assert float(got.min()) == pytest.approx(float(expected.min()), rel=1e-6)
