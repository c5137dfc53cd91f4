"""Rigid transforms: layout, inverse, application to points and vectors, composition."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lisa_hand.geometry import apply_transform, invert_rigid, make_transform, transform_vectors


def _random_transforms(count: int, seed: int = 0, dtype=torch.float64):
    rng = np.random.default_rng(seed)
    rotmats = torch.as_tensor(Rotation.random(count, random_state=seed).as_matrix(), dtype=dtype)
    translations = torch.as_tensor(rng.uniform(-0.2, 0.2, (count, 3)), dtype=dtype)
    return rotmats, translations


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_make_transform_layout(dtype):
    rotmats, translations = _random_transforms(4, dtype=dtype)
    transforms = make_transform(rotmats, translations)
    assert transforms.shape == (4, 4, 4) and transforms.dtype == dtype
    assert torch.equal(transforms[:, :3, :3], rotmats)
    assert torch.equal(transforms[:, :3, 3], translations)
    assert torch.equal(
        transforms[:, 3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype).expand(4, 4)
    )


def test_invert_rigid_is_the_inverse():
    transforms = make_transform(*_random_transforms(8, seed=1))
    inverse = invert_rigid(transforms)
    eye = torch.eye(4, dtype=torch.float64).expand(8, 4, 4)
    torch.testing.assert_close(inverse @ transforms, eye)
    torch.testing.assert_close(transforms @ inverse, eye)
    torch.testing.assert_close(inverse, torch.linalg.inv(transforms))


def test_apply_transform_matches_homogeneous_product():
    transforms = make_transform(*_random_transforms(3, seed=2))
    points = torch.as_tensor(np.random.default_rng(2).standard_normal((3, 5, 3)))
    homogeneous = torch.cat([points, torch.ones(3, 5, 1, dtype=torch.float64)], dim=-1)
    expected = (transforms[:, None] @ homogeneous[..., None])[..., :3, 0]
    torch.testing.assert_close(apply_transform(transforms, points), expected)


def test_apply_transform_broadcasts_one_transform_and_bone_batches():
    transforms = make_transform(*_random_transforms(6, seed=3)).reshape(2, 3, 4, 4)
    points = torch.as_tensor(np.random.default_rng(3).standard_normal((2, 3, 7, 3)))
    got = apply_transform(transforms, points)
    assert got.shape == (2, 3, 7, 3)
    torch.testing.assert_close(got[1, 2], apply_transform(transforms[1, 2], points[1, 2]))
    single = apply_transform(transforms[0, 0], points[0, 0])
    torch.testing.assert_close(
        single, points[0, 0] @ transforms[0, 0, :3, :3].T + transforms[0, 0, :3, 3]
    )


def test_transform_vectors_ignores_translation():
    rotmats, translations = _random_transforms(2, seed=4)
    vectors = torch.as_tensor(np.random.default_rng(4).standard_normal((2, 5, 3)))
    got = transform_vectors(make_transform(rotmats, translations), vectors)
    torch.testing.assert_close(got, (rotmats[:, None] @ vectors[..., None])[..., 0])
    torch.testing.assert_close(got.norm(dim=-1), vectors.norm(dim=-1))


def test_composition_and_round_trip():
    first, second = make_transform(*_random_transforms(2, seed=5)).unbind(0)
    points = torch.as_tensor(np.random.default_rng(5).standard_normal((9, 3)))
    torch.testing.assert_close(
        apply_transform(first @ second, points),
        apply_transform(first, apply_transform(second, points)),
    )
    torch.testing.assert_close(
        apply_transform(invert_rigid(first), apply_transform(first, points)), points
    )


def test_gradients_flow_through_make_and_apply():
    rotmats, translations = _random_transforms(1, seed=6)
    translations.requires_grad_(True)
    points = torch.tensor(np.random.default_rng(6).standard_normal((1, 4, 3)), requires_grad=True)

    def posed(translations, points):
        return apply_transform(invert_rigid(make_transform(rotmats, translations)), points)

    assert torch.autograd.gradcheck(posed, (translations, points))
