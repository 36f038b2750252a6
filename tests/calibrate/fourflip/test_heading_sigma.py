"""The four-flip report's heading sigma: every correlation of a channel's direction, offset and gain carried."""

import numpy as np
import pytest

from calibrate.diagnosis.robust import heading_sigma_deg
from calibrate.fourflip._mlfit import fit_ml
from calibrate.fourflip.diagnosis import _heading_sigma
from calibrate.fourflip.effects import VARIANTS
from calibrate.fourflip.fit import physics_from_harmonics
from compass.sim.bench import BenchSamples

N_HEADINGS = 72


def _heading_rad(reference, physics) -> np.ndarray:
    """A level housing's heading read through ``physics`` from outputs ``reference`` makes, every 5 degrees."""
    psi = np.linspace(0.0, 2 * np.pi, N_HEADINGS, endpoint=False)
    dip = np.radians(reference.dip_deg)
    b = reference.field_norm * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                                np.full_like(psi, -np.sin(dip))])
    out = reference.offsets + reference.gains * (b @ reference.directions.T)
    m = ((out - physics.offsets) / physics.gains) @ np.linalg.pinv(physics.directions).T
    return np.arctan2(-m[:, 1], m[:, 0])


@pytest.fixture(scope="module")
def warm_up_fit(tmp_path_factory):
    from calibrate import calibrate_fourflip
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    path, _ = write_fourflip(simulate_fourflip(seed=200, effects=("offset_drift",)),
                             tmp_path_factory.mktemp("warm") / "rec.csv")
    rec = read_fourflip(path)
    samples = BenchSamples.from_recording(rec)
    start = physics_from_harmonics(rec, 50.0, 1.0)
    noise = np.array(calibrate_fourflip(rec, diagnose=False).noise)
    warm_up = VARIANTS["offset_drift"][-1]
    return fit_ml(samples, rec.outputs, rec.channels, start, noise, effects=(warm_up,))


def test_heading_sigma_is_the_fits_covariance_taken_through_the_runtime(warm_up_fit):
    """Reference relation: the stated heading sigma is the RMS over headings of ``sqrt(j^T C j)``, ``j`` the
    runtime heading's derivative by every fit parameter (finite differences through the layout), ``C`` the
    fit's covariance; the per-channel formula taking direction, offset and gain as independent is not."""
    fit = warm_up_fit
    x, phys = fit.x, fit.physics
    h0 = _heading_rad(phys, phys)
    jac = np.zeros((N_HEADINGS, x.size))
    for j in range(x.size):
        step = 1e-6 * max(1.0, abs(x[j]))
        moved = x.copy()
        moved[j] += step
        jac[:, j] = np.angle(np.exp(1j * (_heading_rad(phys, fit.layout.physics(moved)) - h0))) / step
    reference = np.degrees(np.sqrt(np.mean(np.einsum("hi,ij,hj->h", jac, np.nan_to_num(fit.covariance), jac))))
    assert _heading_sigma(fit) == pytest.approx(reference, rel=0.005)
    c = len(phys.gains)
    var = np.diag(fit.covariance)[:4 * c].reshape(c, 4)[:, 2:] * phys.gains[:, None] ** 2
    independent = heading_sigma_deg(phys.directions, fit.direction_covariance, var, phys.gains, phys.dip_deg,
                                    phys.field_norm)
    assert abs(independent / reference - 1.0) > 0.02  # 3 % on this recording, 18 % median on bench_loop's


def test_joint_covariance_keeps_the_files_sigmas(warm_up_fit):
    """The joint block's diagonal parts are the file's direction covariance and (to the start's gain against the
    fitted one) its offset and gain variances: nothing stated in the file changes."""
    fit = warm_up_fit
    joint = fit.channel_covariance()
    np.testing.assert_allclose(joint[:, :3, :3], fit.direction_covariance, rtol=1e-9, atol=1e-18)
    c = len(fit.physics.gains)
    var = np.diag(fit.covariance)[:4 * c].reshape(c, 4)[:, 2:] * fit.physics.gains[:, None] ** 2
    np.testing.assert_allclose(joint[:, 4, 4], var[:, 1], rtol=1e-9)
    np.testing.assert_allclose(joint[:, 3, 3], var[:, 0], rtol=0.05)


def test_an_undetermined_parameter_leaves_the_channels_other_terms(warm_up_fit):
    """A log gain the fit could not determine (its covariance row and column NaN) makes NaN only the gain's
    row and column of that channel's joint covariance; its direction and offset terms are those of the fit
    with the gain known."""
    from dataclasses import replace

    fit = warm_up_fit
    cov = fit.covariance.copy()
    cov[3, :] = cov[:, 3] = np.nan  # channel 0's log gain
    joint, known = replace(fit, covariance=cov).channel_covariance(), fit.channel_covariance()
    assert np.all(np.isnan(joint[0, 4, :])) and np.all(np.isnan(joint[0, :, 4]))
    assert np.all(np.isfinite(joint[0, :4, :4]))
    # without the gain's correlations the rest of the block is the known one with the gain's column removed
    expected = replace(fit, covariance=np.nan_to_num(cov, nan=0.0)).channel_covariance()
    np.testing.assert_allclose(joint[0, :4, :4], expected[0, :4, :4], rtol=1e-12)
    np.testing.assert_allclose(joint[1:], known[1:], rtol=1e-12)
