"""The shared pose prior and joint-limit term: zero where they should be, closed-form values."""

import math

import pytest
import torch

from lisa_hand.fitting.priors import (
    finger_pose_prior,
    joint_limit_excess,
    prior_mean_fingers,
)
from lisa_hand.handmodel.poses import JOINT_LIMITS, named_pose, pose_to_angles


def test_named_poses_are_inside_the_limits():
    for name in ("flat", "relaxed", "fist"):
        pose = named_pose(name)[None]
        assert joint_limit_excess(pose).item() == pytest.approx(0.0, abs=1e-10)


def test_limit_excess_is_the_squared_overshoot_of_one_flexion():
    pose = torch.zeros(1, 48, dtype=torch.float64)
    angles = pose_to_angles(pose)
    upper = JOINT_LIMITS.to(angles)[..., 1]
    # Flex the index MCP (the first finger joint) 0.3 rad beyond its upper flexion limit: find
    # the axis-angle direction that raises its flexion most, then bisect for the angle.
    over = 0.3
    direction = torch.zeros(48, dtype=torch.float64)
    best = None
    for axis in range(3):
        for sign in (1.0, -1.0):
            trial = pose.clone()
            trial[0, 3 + axis] = sign * 0.1
            delta = pose_to_angles(trial)[0, 0, 0] - angles[0, 0, 0]
            if delta > 0.09 and (best is None or delta > best[0]):
                best = (delta, axis, sign)
    assert best is not None
    _, axis, sign = best
    direction[3 + axis] = sign
    # bisection for the angle that reaches the target flexion
    low, high = 0.0, 3.0
    for _ in range(60):
        mid = 0.5 * (low + high)
        flex = pose_to_angles((pose + mid * direction)[None, 0])[0, 0, 0]
        low, high = (mid, high) if flex < upper[0, 0] + over else (low, mid)
    trial = pose + low * direction
    excess = joint_limit_excess(trial).item()
    others = pose_to_angles(trial)[0]
    lim = JOINT_LIMITS.to(others)
    rest = (torch.relu(lim[..., 0] - others) + torch.relu(others - lim[..., 1])).square()
    rest[0, 0] = 0.0
    assert excess == pytest.approx(over**2 + rest.sum().item(), rel=1e-6)


def test_finger_prior_is_zero_at_its_mean_and_a_mean_of_squares_elsewhere():
    mean = prior_mean_fingers("relaxed", dtype=torch.float64)
    pose = torch.cat([torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64), mean])[None]
    assert finger_pose_prior(pose, mean).item() == 0.0  # the global rotation is free
    shifted = pose.clone()
    shifted[0, 3:] += 0.1
    assert finger_pose_prior(shifted, mean).item() == pytest.approx(0.01)
    assert finger_pose_prior(shifted[:, 3:], mean).item() == pytest.approx(0.01)
    flat = prior_mean_fingers("flat", dtype=torch.float64)
    assert torch.equal(flat, torch.zeros(45, dtype=torch.float64))
    assert math.isfinite(finger_pose_prior(pose, flat).item())


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="prior pose"):
        prior_mean_fingers("fist")
    with pytest.raises(ValueError, match="pose must have shape"):
        joint_limit_excess(torch.zeros(48))
    with pytest.raises(ValueError, match="mean_fingers"):
        finger_pose_prior(torch.zeros(1, 48), torch.zeros(48))


def test_limit_term_has_gradients_outside_the_limits_only():
    pose = named_pose("relaxed")[None].clone().requires_grad_(True)
    joint_limit_excess(pose).sum().backward()
    assert pose.grad.abs().max().item() == 0.0
