"""The model of Eq. 4 (Zhou et al. 2010) against an independent forward model."""

import numpy as np
import pytest

from nlpcal.models.zhou2010 import (
    PARAMETER_NAMES,
    Zhou2010Parameters,
    axis_matrix,
    correct,
    correction_matrix,
    forward,
)
from synthetic import PAPER_TRUTH, make_log, sensor_axes, sensor_output

TRUTH = Zhou2010Parameters.from_dict(PAPER_TRUTH)


def test_correction_inverts_the_independent_forward_model():
    samples, field_ideal = make_log(n=200, noise=0.0)
    np.testing.assert_allclose(correct(samples, TRUTH), field_ideal, rtol=0, atol=1e-8)


def test_forward_model_matches_the_independent_one():
    _, field_ideal = make_log(n=200, noise=0.0)
    np.testing.assert_allclose(
        forward(field_ideal, TRUTH), sensor_output(field_ideal, PAPER_TRUTH), rtol=0, atol=1e-8
    )


def test_correction_matrix_is_the_printed_O_p_times_S_p():
    t_printed = sensor_axes(TRUTH.alpha_deg, TRUTH.beta_deg, TRUTH.gamma_deg)
    O_p = np.linalg.inv(t_printed)
    S_p = np.linalg.inv(np.diag(1 + TRUTH.scales))
    np.testing.assert_allclose(correction_matrix(TRUTH), O_p @ S_p, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(axis_matrix(TRUTH), t_printed, rtol=1e-15)
    assert np.allclose(np.tril(correction_matrix(TRUTH), -1), 0)


def test_worked_example_of_the_angle_convention():
    # alpha = 1 deg tilts the x axis out of the horizontal plane toward -z1: a vertical field of
    # 50 000 nT reads -50 000 sin(1 deg) = -872.6 nT on x (docs/model.md).
    out = forward(np.array([[0.0, 0.0, 50000.0]]), Zhou2010Parameters(alpha_deg=1.0))
    np.testing.assert_allclose(out, [[-872.620322, 0.0, 50000.0]], atol=1e-6)
    # gamma = 1 deg turns x toward +y1: a field along y1 reads +sin(1 deg) on x.
    out = forward(np.array([[0.0, 50000.0, 0.0]]), Zhou2010Parameters(gamma_deg=1.0))
    np.testing.assert_allclose(out[0, 0], 872.620322, atol=1e-6)
    # beta = 1 deg tilts y toward +z1.
    out = forward(np.array([[0.0, 0.0, 50000.0]]), Zhou2010Parameters(beta_deg=1.0))
    np.testing.assert_allclose(out[0, 1], 872.620322, atol=1e-6)


def test_parameters_round_trip_and_validation():
    assert Zhou2010Parameters.from_dict(TRUTH.as_dict()) == TRUTH
    assert Zhou2010Parameters.from_vector(TRUTH.as_vector()) == TRUTH
    assert tuple(TRUTH.as_dict()) == PARAMETER_NAMES
    with pytest.raises(KeyError):
        Zhou2010Parameters.from_dict({"z_x": 1.0})
    with pytest.raises(ValueError):
        Zhou2010Parameters.from_vector([1, 2, 3])
