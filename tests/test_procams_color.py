"""Colour calibration on synthetic projector-space captures with a known mixing matrix and response."""

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.color import calibrate_color, locally_linear_weights, mixing_matrix_from_primaries
from edofproj.procams.patterns import color_sample_values

MIXING = np.array([[0.6, 0.1, 0.05], [0.12, 0.55, 0.1], [0.02, 0.15, 0.5]])
BLACK = np.array([0.03, 0.035, 0.025])
GAMMA = np.array([2.2, 1.8, 2.4])


def field(value, shape=(20, 24)):
    return np.broadcast_to(np.asarray(value, float), shape + (3,)).copy()


def captured(inputs):
    """Camera value of uniform projector inputs: black + M u^gamma."""
    return BLACK + (np.asarray(inputs) ** GAMMA) @ MIXING.T


def synthetic_calibration(levels=6, neighbours=6):
    primaries = {
        name: field(captured(color)) for name, color in (("red", (1, 0, 0)), ("green", (0, 1, 0)), ("blue", (0, 0, 1)))
    }
    samples = [(tuple(c), field(captured(c))) for c in color_sample_values(levels)]
    return calibrate_color(primaries, field(BLACK), samples, neighbours=neighbours)


def test_mixing_matrix_is_the_primaries_minus_black():
    red, green, blue = (field(captured(c)) for c in ((1, 0, 0), (0, 1, 0), (0, 0, 1)))
    np.testing.assert_allclose(mixing_matrix_from_primaries(red, green, blue, field(BLACK)), MIXING, atol=1e-12)


def test_camera_to_output_inverts_the_mixing():
    calibration = synthetic_calibration()
    outputs = np.random.default_rng(0).uniform(0, 1, (50, 3))
    np.testing.assert_allclose(calibration.camera_to_output(BLACK + outputs @ MIXING.T), outputs, atol=1e-12)


def test_local_linear_weights_reproduce_affine_maps_and_samples():
    samples = color_sample_values(4)
    queries = np.random.default_rng(1).uniform(0, 1, (200, 3))
    index, weights = locally_linear_weights(queries, samples, neighbours=6)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    affine = lambda x: x @ np.array([[1.0, 0.2, 0.0], [0.1, 0.8, 0.3], [0.0, 0.0, 1.2]]) + 0.1  # noqa: E731
    reconstructed = np.einsum("nk,nkc->nc", weights, affine(samples[index]))
    np.testing.assert_allclose(reconstructed, affine(queries), atol=2e-3)  # regularization: lambda = 1e-3 tr(G)
    exact_index, exact_weights = locally_linear_weights(samples[:5], samples, neighbours=6)
    np.testing.assert_array_equal(exact_weights[:, 0], 1.0)
    np.testing.assert_array_equal(samples[exact_index[:, 0]], samples[:5])


def test_response_and_its_inverse_are_recovered():
    calibration = synthetic_calibration(levels=6)
    np.testing.assert_allclose(calibration.sample_outputs, calibration.sample_inputs**GAMMA, atol=1e-12)
    corners = np.array([[0, 0, 0], [1, 0, 1], [0, 1, 0], [1, 1, 1]], float)
    np.testing.assert_allclose(calibration.input_to_output(corners), corners, atol=1e-12)
    queries = np.random.default_rng(2).uniform(0, 1, (2000, 3))
    truth = queries**GAMMA
    assert np.abs(calibration.input_to_output(queries) - truth).mean() < 0.015  # measured 0.009 (6 levels)
    bright = queries.min(axis=1) > 0.2  # away from black, where u = o^(1/gamma) is steep
    # measured 0.025: the samples are an uneven grid in output space, so the neighbours are lopsided
    assert np.abs(calibration.output_to_input(truth) - queries)[bright].mean() < 0.04


def test_images_are_mapped_per_pixel():
    calibration = synthetic_calibration(levels=3)
    image = np.random.default_rng(3).integers(0, 2, (8, 9, 3)).astype(float)
    np.testing.assert_allclose(calibration.input_to_output(image), image, atol=1e-12)


def test_bad_calibration_data_raise_one_line():
    same = field(captured((1, 0, 0)))
    with pytest.raises(EdofprojError, match="colour-mixing matrix is singular"):
        mixing_matrix_from_primaries(same, same, field(captured((0, 0, 1))), field(BLACK))
    with pytest.raises(EdofprojError, match="--neighbours 3 must be >= 4"):
        synthetic_calibration(levels=2, neighbours=3)
