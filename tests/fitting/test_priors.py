"""The shared pose prior and joint-limit term: zero where they should be, closed-form values."""

import math

import pytest
import torch

from lisa_hand.fitting.priors import (
    COUPLED_FINGERS,
    UNSEEN_FINGERS,
    finger_coupling,
    finger_pose_prior,
    joint_limit_excess,
    prior_mean_fingers,
    thumb_pose_prior,
)
from lisa_hand.handmodel.poses import JOINT_LIMITS, named_pose, pose_to_angles
from lisa_hand.skeleton import FINGER_JOINTS


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


def _flexions(values: dict[str, tuple[float, float, float]]) -> torch.Tensor:
    """[1, 48] a pose with the given fingers' three flexions (local z), the rest zero."""
    pose = torch.zeros(16, 3, dtype=torch.float64)
    for name, chain in values.items():
        pose[list(FINGER_JOINTS[name]), 2] = torch.tensor(chain, dtype=torch.float64)
    return pose.reshape(1, 48)


def test_finger_coupling_pulls_an_unseen_finger_to_its_neighbours_curl():
    assert COUPLED_FINGERS == ("index", "middle", "ring", "pinky")
    pose = _flexions({"index": (0.1, 0.2, 0.0), "middle": (1.3, 1.5, 0.9),
                      "ring": (1.1, 1.7, 0.7), "pinky": (1.0, 1.0, 1.0)})
    pose.requires_grad_(True)
    # the index alone, fully weighted: its neighbour is the middle finger
    index_only = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    value = finger_coupling(pose, index_only)
    assert value.item() == pytest.approx(((1.2 ** 2) + (1.3 ** 2) + (0.9 ** 2)) / 3)
    value.sum().backward()
    grad = pose.grad.reshape(16, 3)
    # gradient 2 w (flexion - neighbour) / 3 on the index's flexions, none on the neighbours
    expected = 2.0 * torch.tensor([0.1 - 1.3, 0.2 - 1.5, 0.0 - 0.9], dtype=torch.float64) / 3
    assert torch.allclose(grad[list(FINGER_JOINTS["index"]), 2], expected)
    others = [j for name in ("middle", "ring", "pinky") for j in FINGER_JOINTS[name]]
    assert float(grad[others].abs().max()) == 0.0
    # the ring finger at half weight: its neighbours are the middle and the pinky (their mean)
    ring_half = torch.tensor([0.0, 0.0, 0.5, 0.0], dtype=torch.float64)
    beside = [(1.3 + 1.0) / 2, (1.5 + 1.0) / 2, (0.9 + 1.0) / 2]
    ring = (1.1, 1.7, 0.7)
    assert finger_coupling(pose, ring_half).item() == pytest.approx(
        0.5 * sum((r - b) ** 2 for r, b in zip(ring, beside, strict=True)) / 3)


def test_the_thumb_prior_is_the_mean_square_of_the_thumbs_nine_values_only():
    assert UNSEEN_FINGERS == COUPLED_FINGERS + ("thumb",)
    mean = prior_mean_fingers("relaxed", dtype=torch.float64)
    pose = torch.cat([torch.zeros(3, dtype=torch.float64), mean])[None].repeat(2, 1)
    pose[1, 3:] += 0.4  # every finger moved: only the thumb's 9 values count
    thumb = [3 * joint + axis for joint in FINGER_JOINTS["thumb"] for axis in range(3)]
    pose[1, thumb[0]] += 0.3  # its first value 0.7 from the mean
    pose.requires_grad_(True)
    value = thumb_pose_prior(pose, mean)
    assert value[0].item() == 0.0
    assert value[1].item() == pytest.approx((0.7 ** 2 + 8 * 0.4 ** 2) / 9)
    value.sum().backward()
    others = [index for index in range(48) if index not in thumb]
    assert float(pose.grad[:, others].abs().max()) == 0.0
    assert pose.grad[1, thumb[0]].item() == pytest.approx(2 * 0.7 / 9)
    # its sum with the other fingers' share is finger_pose_prior (9 of the 45 values)
    rest = pose.detach().clone()
    rest[:, thumb] = torch.cat([torch.zeros(3, dtype=torch.float64), mean])[thumb]
    assert (value[1] * 9 + finger_pose_prior(rest, mean)[1] * 45).item() == pytest.approx(
        finger_pose_prior(pose.detach(), mean)[1].item() * 45)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="prior pose"):
        prior_mean_fingers("fist")
    with pytest.raises(ValueError, match="pose must have shape"):
        joint_limit_excess(torch.zeros(48))
    with pytest.raises(ValueError, match="mean_fingers"):
        finger_pose_prior(torch.zeros(1, 48), torch.zeros(48))
    with pytest.raises(ValueError, match="weights"):
        finger_coupling(torch.zeros(1, 48), torch.zeros(5))
    with pytest.raises(ValueError, match="mean_fingers"):
        thumb_pose_prior(torch.zeros(1, 48), torch.zeros(9))


def test_limit_term_has_gradients_outside_the_limits_only():
    pose = named_pose("relaxed")[None].clone().requires_grad_(True)
    joint_limit_excess(pose).sum().backward()
    assert pose.grad.abs().max().item() == 0.0
