"""tools/bench_broad.py's time-scale split of the tilt error (``--bands``): reference relations on synthetic series."""


import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests._paths import load_tool


@pytest.fixture(scope="module")
def bench():
    return load_tool("bench_broad")


@pytest.mark.parametrize("period_s", [0.1, 0.6, 2.0, 6.0, 40.0])
def test_a_sinusoid_splits_as_the_moving_means_transfer_functions_say(bench, period_s):
    """A tilt error turning with one period (RMS 1 deg over both axes): each moving mean of ``n`` samples passes
    ``H = sin(pi n f / fs) / (n sin(pi f / fs))`` of it, so band ``i`` holds ``|H_0 ... H_(i-1) (1 - H_i)|`` and the
    last ``|H_0 ... H_3|``; the band that holds the period carries most of it."""
    rate_hz = 100.0
    t = np.arange(int(400 * rate_hz)) / rate_hz
    error = np.stack([np.sin(2 * np.pi * t / period_s), np.cos(2 * np.pi * t / period_s)], axis=1)
    rows = (t > 60.0) & (t < 340.0)  # away from the moving means' edges
    cells = bench._bands(error, rows, rate_hz)
    x = np.pi / (period_s * rate_hz)
    h = [np.sin(n * x) / (n * np.sin(x)) for n in (round(s * rate_hz) for s in bench.BANDS_S)]
    expected = [abs(np.prod(h[:i]) * (1.0 - h[i])) for i in range(len(h))] + [abs(np.prod(h))]
    np.testing.assert_allclose(cells, expected, atol=0.01)
    home = int(np.searchsorted(bench.BANDS_S, period_s))
    assert cells[home] == max(cells) and cells[home] > 0.7


def test_the_tilt_error_is_the_world_frame_tilt_and_ignores_heading(bench):
    """An estimate turned 1 deg about world x and 30 deg about the vertical from the reference: the tilt error is
    (1, 0) deg to first order, whatever the heading; rows without a reference count as zero."""
    ref = Rotation.from_euler("ZYX", [[40, 10, -5], [120, -20, 15]], degrees=True)
    turn = Rotation.from_euler("x", 1.0, degrees=True)
    est = turn * ref
    ref_q = ref.as_quat(scalar_first=True)
    got = bench._tilt_error_deg(est.as_quat(scalar_first=True), ref_q)
    np.testing.assert_allclose(got, [[1.0, 0.0], [1.0, 0.0]], atol=1e-9)
    spun = Rotation.from_euler("z", 30.0, degrees=True) * ref
    np.testing.assert_allclose(bench._tilt_error_deg(spun.as_quat(scalar_first=True), ref_q), 0.0, atol=1e-9)
    ref_q[1] = np.nan
    np.testing.assert_array_equal(bench._tilt_error_deg(est.as_quat(scalar_first=True), ref_q)[1], [0.0, 0.0])


def test_write_docs_without_bands_is_refused(bench, capsys):
    """``--write-docs`` writes the ``--bands`` table only: asked for in another mode it is an error, not a no-op."""
    with pytest.raises(SystemExit) as stop:
        bench.main(["--write-docs"])
    assert stop.value.code == 2
    assert "--write-docs writes the --bands table only" in capsys.readouterr().err


@pytest.mark.parametrize("freq_hz", [0.3, 1.0])
def test_the_leaks_time_scales_are_one_over_omega_for_a_sinusoid(bench, freq_hz):
    """``--leak``: for a motion at ``w`` the first-order relations give ``tau |q| / |r - q| = 1 / (w tau) tau``, and a
    sinusoid's ``sqrt(<l^2> / <l'^2>)`` is ``1 / w`` (both after the start's transient); its density at a 1 s bandwidth
    is that of a sinusoid through the pole, ``1 / (1 + (w T)^2)`` of its variance times ``T``."""
    rate, tau, w = 200.0, 2.0, 2.0 * np.pi * freq_hz
    t = np.arange(int(60.0 * rate)) / rate
    motion = np.sin(w * t)
    alpha = -np.expm1(-1.0 / (rate * tau))
    from scipy.signal import lfilter

    leak = lfilter([alpha], [1.0, alpha - 1.0], motion)
    rows = t > 30.0
    estimate, scale, density = bench.leak_time_scales(leak, motion - leak, rows, tau, rate)
    assert estimate == pytest.approx(1.0 / w, rel=0.02)
    assert scale == pytest.approx(1.0 / w, rel=0.02)
    assert density == pytest.approx(1.0 / (1.0 + w**2), rel=0.05)
