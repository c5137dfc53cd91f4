"""Array inputs (``lisa_hand.utils.arrays``): tensors with grad on any device and array-likes
become numpy; what is not an array is one error naming the argument."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.utils.arrays import as_numpy


def test_tensors_and_array_likes_become_numpy():
    tensor = torch.arange(6.0).reshape(2, 3).requires_grad_(True)
    array = as_numpy(tensor * 2, "points")
    assert isinstance(array, np.ndarray) and np.array_equal(array, np.arange(6.0).reshape(2, 3) * 2)
    assert np.array_equal(as_numpy([[1, 2, 3]], "points"), np.array([[1, 2, 3]]))


def test_a_ragged_input_is_one_error_naming_the_argument():
    with pytest.raises(TypeError, match="points must be an array, got list"):
        as_numpy([[1.0], [1.0, 2.0]], "points")
