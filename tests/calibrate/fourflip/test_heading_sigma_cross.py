"""The heading sigma's offsets across channels through a response curve: each offset's error moves its component
by ``dV0 / (K g'(x))`` at the heading's ``x``, as inverting the curve does."""

import numpy as np
import pytest

from calibrate.diagnosis.robust import heading_sigma_deg
from compass.response import CubicResponse

N_HEADINGS = 72
FIELD, DIP = 50.0, 60.0


def _heading_rad(responses, offsets, directions) -> np.ndarray:
    """A level housing's heading every 5 degrees, read by inverting ``responses`` with their offsets replaced by
    ``offsets`` from the outputs the true ``responses`` give."""
    psi = np.linspace(0.0, 2 * np.pi, N_HEADINGS, endpoint=False)
    dip = np.radians(DIP)
    b = FIELD * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                 np.full_like(psi, -np.sin(dip))])
    x = b @ directions.T
    read = np.column_stack([CubicResponse(o, r.gain, r.x_range, cubic=r.cubic, quadratic=r.quadratic)
                            .field_component(r.output(x[:, c]))[0]
                            for c, (r, o) in enumerate(zip(responses, offsets))])
    m = read @ np.linalg.pinv(directions).T
    return np.arctan2(-m[:, 1], m[:, 0])


def test_correlated_offsets_through_a_curve_move_the_heading_as_inverting_it_does():
    """Reference relation: with only the offsets uncertain (correlated across channels), the heading sigma is the
    RMS over headings of ``sqrt(J C_V J^T)``, ``J`` the heading's finite-difference derivative by each offset
    through the curves' inversion; the levers ``1 / K`` (the linear ones) are not."""
    rng = np.random.default_rng(4)
    directions = np.eye(3) + 0.05 * rng.normal(size=(3, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    gains = np.array([0.02, 0.025, 0.018])
    curves = np.array([[2e-3, -4e-5, 0.0], [-1.5e-3, -3e-5, 0.0], [1e-3, -5e-5, 0.0]])
    responses = [CubicResponse(2.5, k, (-FIELD, FIELD), cubic=cv[1], quadratic=cv[0]) for k, cv in zip(gains, curves)]
    sigma = np.array([4e-4, 6e-4, 5e-4])
    corr = np.array([[1.0, 0.8, -0.6], [0.8, 1.0, -0.5], [-0.6, -0.5, 1.0]])
    offsets_cov = corr * np.outer(sigma, sigma)
    offsets = np.array([r.offset for r in responses])
    h0 = _heading_rad(responses, offsets, directions)
    jac = np.empty((N_HEADINGS, 3))
    for c in range(3):
        step = np.zeros(3)
        step[c] = 1e-3 * sigma[c]
        jac[:, c] = np.angle(np.exp(1j * (_heading_rad(responses, offsets + step, directions) - h0))) / step[c]
    reference = np.degrees(np.sqrt(np.mean(np.einsum("hi,ij,hj->h", jac, offsets_cov, jac))))
    joint = np.zeros((3, 8, 8))
    joint[:, 3, 3] = sigma**2
    args = (directions, np.zeros((3, 3, 3)), np.column_stack([sigma**2, np.zeros(3)]), gains, DIP, FIELD, N_HEADINGS)
    stated = heading_sigma_deg(*args, offset_covariance=offsets_cov, channel_covariance=joint, curves=curves)
    assert stated == pytest.approx(reference, rel=1e-4)
    linear = heading_sigma_deg(*args, offset_covariance=offsets_cov, channel_covariance=joint[:, :5, :5])
    assert abs(linear / reference - 1.0) > 0.02
