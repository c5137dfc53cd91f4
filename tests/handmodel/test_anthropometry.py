"""Hand model v2's shape draws against the anthropometric table they come from."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.handmodel import HandShape
from lisa_hand.handmodel.anthropometry import (
    ANTHROPOMETRIC_CLIP,
    ANTHROPOMETRIC_TABLE,
    MEASUREMENTS,
    population_moments,
    sample_anthropometric_shape,
    sample_measurements,
    shape_measurements,
)

NUM = 2000


@pytest.fixture(scope="module")
def draws():
    generator = torch.Generator().manual_seed(2024)
    return [sample_measurements(generator) for _ in range(NUM)]


def _values(draws) -> np.ndarray:
    return np.array([d.values for d in draws])


def test_population_moments_are_the_mixture_of_the_table():
    mean, cov = population_moments()
    # Hand length by hand: the mean of the two sexes' means, and the mixture variance
    # 0.5 (s_f^2 + s_m^2) + 0.25 (m_m - m_f)^2.
    assert mean[0] == pytest.approx(0.5 * (0.175 + 0.190))
    variance = 0.5 * (0.009**2 + 0.010**2) + 0.25 * (0.190 - 0.175) ** 2
    assert cov[0, 0] == pytest.approx(variance)
    # Length and breadth: 0.5 (r s_f,L s_f,B + r s_m,L s_m,B) + 0.25 dL dB.
    covariance = 0.5 * 0.65 * (0.009 * 0.004 + 0.010 * 0.005) + 0.25 * 0.015 * 0.010
    assert cov[0, 1] == pytest.approx(covariance)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_sample_means_sds_and_correlation_match_the_table(draws):
    values = _values(draws)
    mean, cov = population_moments()
    std = np.sqrt(np.diag(cov))
    # Means within 4 standard errors, SDs within 10 %, for every measurement.
    assert np.all(np.abs(values.mean(0) - mean) < 4.0 * std / math.sqrt(NUM))
    assert np.all(np.abs(values.std(0) / std - 1.0) < 0.10)
    # Correlation of hand length with breadth (and with palm thickness), within ~4 SE.
    corr = np.corrcoef(values.T)
    expected = cov / np.outer(std, std)
    assert corr[0, 1] == pytest.approx(expected[0, 1], abs=0.06)
    assert corr[0, 2] == pytest.approx(expected[0, 2], abs=0.06)
    assert 0.7 < expected[0, 1] < 0.85  # the mixture is more correlated than a sex (0.65)


def test_sexes_and_digit_ratio_by_sex(draws):
    female = np.array([d.female for d in draws])
    assert abs(female.mean() - 0.5) < 4.0 * 0.5 / math.sqrt(NUM)
    values = _values(draws)
    ratio = MEASUREMENTS.index("digit_ratio")
    for sex, mask in (("female", female), ("male", ~female)):
        table_mean = ANTHROPOMETRIC_TABLE[sex]["mean"][ratio]
        table_std = ANTHROPOMETRIC_TABLE[sex]["std"][ratio]
        error = abs(values[mask, ratio].mean() - table_mean)
        assert error < 4.0 * table_std / math.sqrt(mask.sum())
    assert values[female, 0].mean() < values[~female, 0].mean() - 0.01  # shorter female hands


def test_draws_are_clipped_seeded_and_give_valid_shapes():
    shapes, measured = [], []
    for seed in range(200):
        generator = torch.Generator().manual_seed(seed)
        measured.append(sample_measurements(torch.Generator().manual_seed(seed)))
        shapes.append(sample_anthropometric_shape(generator))
    for draw in measured:
        for name, value in zip(MEASUREMENTS, draw.values, strict=True):
            low, high = ANTHROPOMETRIC_CLIP[name]
            assert low <= value <= high
    assert all(isinstance(shape, HandShape) for shape in shapes)  # validated on construction
    again = sample_anthropometric_shape(torch.Generator().manual_seed(0))
    assert again == shapes[0] and shapes[0] != shapes[1]
    # The shape stands for the measurements it came from (when no parameter was clipped).
    for draw, shape in zip(measured, shapes, strict=True):
        back = shape_measurements(shape)
        assert back["hand_length"] == draw["hand_length"]
        assert back["index_ratio"] == draw["index_ratio"]
        if 0.76 < shape.palm_width < 1.29:
            assert back["hand_breadth"] == pytest.approx(draw["hand_breadth"], rel=1e-9)
        if 0.87 < shape.ring_ratio < 1.05:
            assert back["digit_ratio"] == pytest.approx(draw["digit_ratio"], rel=1e-9)
    lengths = np.array([s.hand_length for s in shapes])
    assert 0.160 < np.percentile(lengths, 5) and np.percentile(lengths, 95) < 0.205


def test_bad_generator_is_rejected():
    with pytest.raises(TypeError, match="torch.Generator"):
        sample_measurements(0)
