"""Rotations against scipy, round trips, and gradients (including at exactly zero angle)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lisa_hand.geometry import axis_angle_to_matrix, matrix_to_axis_angle, skew

# Angles from exactly 0 to exactly pi, through the Taylor/closed-form switch (theta = 1e-3).
ANGLES = [
    0.0,
    1e-12,
    1e-8,
    1e-5,
    9.99e-4,
    1.001e-3,
    0.01,
    0.3,
    1.0,
    2.0,
    3.0,
    math.pi - 1e-6,
    math.pi,
]


def _axis_angles(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    axes = rng.standard_normal((len(ANGLES), 4, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    return (axes * np.asarray(ANGLES)[:, None, None]).reshape(-1, 3)


@pytest.mark.parametrize(("dtype", "atol"), [(torch.float64, 1e-14), (torch.float32, 1e-6)])
def test_axis_angle_to_matrix_matches_scipy(dtype, atol):
    axis_angle = _axis_angles()
    expected = Rotation.from_rotvec(axis_angle).as_matrix()
    got = axis_angle_to_matrix(torch.as_tensor(axis_angle, dtype=dtype))
    assert got.dtype == dtype
    np.testing.assert_allclose(got.double().numpy(), expected, atol=atol, rtol=0)


def test_zero_angle_is_exactly_identity_and_batch_shape_kept():
    rotmats = axis_angle_to_matrix(torch.zeros(2, 5, 3, dtype=torch.float64))
    assert rotmats.shape == (2, 5, 3, 3)
    assert torch.equal(rotmats, torch.eye(3, dtype=torch.float64).expand(2, 5, 3, 3))


def test_rotation_matrices_are_orthonormal_with_unit_determinant():
    rotmats = axis_angle_to_matrix(torch.as_tensor(_axis_angles(1)))
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(rotmats @ rotmats.transpose(-1, -2), eye.expand_as(rotmats))
    torch.testing.assert_close(
        torch.linalg.det(rotmats), torch.ones(len(rotmats), dtype=torch.float64)
    )


def test_matrix_to_axis_angle_round_trip_below_pi():
    axis_angle = torch.as_tensor(_axis_angles(2))
    keep = axis_angle.norm(dim=-1) < math.pi - 1e-3  # the axis is ambiguous only at pi
    axis_angle = axis_angle[keep]
    recovered = matrix_to_axis_angle(axis_angle_to_matrix(axis_angle))
    torch.testing.assert_close(recovered, axis_angle, atol=1e-12, rtol=0)


@pytest.mark.parametrize("angle", [math.pi - 1e-3, math.pi - 1e-7, math.pi])
def test_matrix_to_axis_angle_near_pi(angle):
    rng = np.random.default_rng(3)
    axes = rng.standard_normal((16, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    rotmats = torch.as_tensor(Rotation.from_rotvec(axes * angle).as_matrix())
    recovered = matrix_to_axis_angle(rotmats)
    # At pi, +axis and -axis are the same rotation: compare the angle and the rotation itself.
    torch.testing.assert_close(
        recovered.norm(dim=-1), torch.full((16,), angle, dtype=torch.float64)
    )
    torch.testing.assert_close(axis_angle_to_matrix(recovered), rotmats, atol=1e-7, rtol=0)
    assert recovered.norm(dim=-1).max() <= math.pi + 1e-12


def test_matrix_to_axis_angle_matches_scipy_on_random_rotations():
    rotations = Rotation.random(64, random_state=4)
    got = matrix_to_axis_angle(torch.as_tensor(rotations.as_matrix()))
    np.testing.assert_allclose(got.numpy(), rotations.as_rotvec(), atol=1e-10)


def test_matrix_to_axis_angle_float32():
    rotations = Rotation.random(32, random_state=5)
    got = matrix_to_axis_angle(torch.as_tensor(rotations.as_matrix(), dtype=torch.float32))
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), rotations.as_rotvec(), atol=2e-5)


@pytest.mark.parametrize(
    "axis_angle",
    [
        [0.3, -0.7, 0.2],  # closed form
        [0.0, 0.0, 0.0],  # exactly zero
        [1e-5, -2e-5, 3e-6],  # Taylor branch
        [5.7e-4, 5.7e-4, 5.7e-4],  # just below the switch (|v| = 0.99e-3)
        [5.8e-4, 5.8e-4, 5.8e-4],  # just above it
        [2.9, 0.5, -0.3],  # near pi
    ],
)
def test_axis_angle_to_matrix_gradcheck(axis_angle):
    inputs = torch.tensor([axis_angle], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(axis_angle_to_matrix, (inputs,), eps=1e-7, atol=1e-8)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_jacobian_at_zero_is_the_skew_basis(dtype):
    # d R / d v_i at v = 0 is [e_i]_x: finite (no NaN from |v|) and exact.
    inputs = torch.zeros(3, dtype=dtype, requires_grad=True)
    jacobian = torch.autograd.functional.jacobian(axis_angle_to_matrix, inputs)  # [3, 3, 3]
    assert torch.isfinite(jacobian).all()
    expected = skew(torch.eye(3, dtype=dtype))  # [3 (i), 3, 3]
    torch.testing.assert_close(jacobian.permute(2, 0, 1), expected)


def test_matrix_to_axis_angle_gradcheck():
    rotmats = torch.as_tensor(Rotation.from_rotvec([[0.4, -1.1, 0.6]]).as_matrix())
    rotmats.requires_grad_(True)
    assert torch.autograd.gradcheck(matrix_to_axis_angle, (rotmats,), eps=1e-7, atol=1e-7)


def test_skew_is_the_cross_product():
    rng = np.random.default_rng(6)
    vectors, others = (torch.as_tensor(rng.standard_normal((2, 7, 3))) for _ in range(2))
    got = (skew(vectors) @ others[..., None])[..., 0]
    torch.testing.assert_close(got, torch.linalg.cross(vectors, others))


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"axis_angle must have shape \[\.\.\., 3\], got \(2, 4\)"):
        axis_angle_to_matrix(torch.zeros(2, 4))
    with pytest.raises(ValueError, match=r"rotmats must have shape \[\.\.\., 3, 3\], got \(3, 4\)"):
        matrix_to_axis_angle(torch.zeros(3, 4))
