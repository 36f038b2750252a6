"""BROAD trials: reader, frames, the benchmark's error metric, and `compass evaluate` end to end.

Data: the BROAD benchmark (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021,
doi:10.3390/data6070072), CC BY 4.0, in ``../shared/data/broad/``.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat
from scipy.spatial.transform import Rotation

from compass.evaluation import error_series, orientation_errors
from compass.io.broad import NWU_FROM_ENU, enu_to_nwu, nwu_to_enu, read_broad
from compass.io.table import RecordingError
from tests._paths import SHARED

BROAD = SHARED / "data" / "broad"
TRIAL = BROAD / "02_undisturbed_slow_rotation_B.mat"
needs_data = pytest.mark.skipif(not TRIAL.exists(), reason=f"BROAD data not found at {BROAD}")


@pytest.fixture(scope="module")
def trial():
    return read_broad(TRIAL)


@needs_data
def test_reader_units_frames_and_dropouts(trial):
    n = len(trial)
    assert trial.name == "02_undisturbed_slow_rotation_B"
    assert trial.rate_hz == pytest.approx(285.714, abs=1e-3)
    for a in (trial.gyro_rad_s, trial.accel_m_s2, trial.mag_ut, trial.ref_pos_m):
        assert a.shape == (n, 3)
    assert trial.ref_quat_enu.shape == (n, 4) and trial.movement.dtype == bool
    dropouts = ~trial.ref_valid
    assert 0 < dropouts.sum() < 0.1 * n and np.all(np.isnan(trial.ref_quat_enu[dropouts]))
    assert trial.t_s[1] == pytest.approx(1.0 / trial.rate_hz)
    # the reference maps body to the world: gravity's specific force points up, the field north and down
    rest = trial.ref_valid & ~trial.movement
    r_nwu = enu_to_nwu(Rotation.from_quat(trial.ref_quat_enu[rest], scalar_first=True))
    acc_w = np.median(r_nwu.apply(trial.accel_m_s2[rest]), axis=0)
    np.testing.assert_allclose(acc_w, [0.0, 0.0, 9.81], atol=0.15)
    mag_w = np.median(r_nwu.apply(trial.mag_ut[rest]), axis=0)
    assert mag_w[0] > 10 and abs(mag_w[1]) < 2 and mag_w[2] < -35  # NWU: north, no west, down
    dip = np.degrees(np.arctan2(-mag_w[2], mag_w[0]))
    assert 65 < dip < 75  # Berlin
    nwu, enu = trial.reference("nwu"), trial.reference("enu")
    assert len(nwu) == trial.ref_valid.sum()
    np.testing.assert_allclose((nwu * enu_to_nwu(enu).inv()).magnitude(), 0.0, atol=1e-9)


def test_enu_nwu_conversion():
    np.testing.assert_allclose(NWU_FROM_ENU.apply([[0, 1, 0], [1, 0, 0], [0, 0, 1]]),
                               [[1, 0, 0], [0, -1, 0], [0, 0, 1]], atol=1e-12)  # north, east = -west, up
    r = Rotation.from_euler("ZYX", [[30, 10, -5], [200, -40, 170]], degrees=True)
    np.testing.assert_allclose((nwu_to_enu(enu_to_nwu(r)) * r.inv()).magnitude(), 0, atol=1e-12)
    # a housing whose +X points east has heading 90 (SPEC: clockwise from north) in NWU
    east = Rotation.from_euler("z", 0, degrees=True)  # body X = ENU X = east
    z, _, _ = enu_to_nwu(east).as_euler("ZYX", degrees=True)
    assert (-z) % 360 == pytest.approx(90.0)


def _synthetic(n=2000, seed=3):
    rng = np.random.default_rng(seed)
    ref = Rotation.random(n, random_state=rng)
    h = rng.uniform(-20, 20, n)
    i = rng.uniform(0, 15, n)
    axis_az = rng.uniform(0, 2 * np.pi, n)  # a horizontal axis for the inclination part
    tilt = Rotation.from_rotvec(np.radians(i)[:, None] * np.column_stack([np.cos(axis_az), np.sin(axis_az),
                                                                          np.zeros(n)]))
    est = Rotation.from_euler("z", h[:, None], degrees=True) * tilt * ref
    return ref, est, h, i


def test_metric_recovers_known_heading_and_inclination_errors():
    ref, est, h, i = _synthetic()
    heading, signed, inclination = orientation_errors(est, ref)
    np.testing.assert_allclose(signed, h, atol=1e-9)
    np.testing.assert_allclose(heading, np.abs(h), atol=1e-9)
    np.testing.assert_allclose(inclination, i, atol=1e-6)
    # an estimate and reference in NWU give the same errors as in ENU (conversion about the vertical)
    for got, want in zip(orientation_errors(enu_to_nwu(est), enu_to_nwu(ref)), (heading, signed, inclination)):
        np.testing.assert_allclose(got, want, atol=1e-6)
    # error rotation on the body side instead is not a heading error when the body is tilted: no free pass
    body = orientation_errors(ref * Rotation.from_euler("z", 5, degrees=True), ref)[2]
    assert np.max(body) > 4.0


def test_error_series_masks_offset_and_nan_rows():
    ref, est, h, i = _synthetic(n=1000, seed=5)
    est = Rotation.from_euler("z", 10, degrees=True) * ref  # constant 10 degree heading offset only
    q_ref = ref.as_quat(scalar_first=True)
    q_est = est.as_quat(scalar_first=True)
    q_ref[100:150] = np.nan
    q_est[900:] = np.nan  # outside the movement phase: never scored
    movement = np.zeros(1000, bool)
    movement[50:900] = True
    s = error_series(q_est, q_ref, movement, rate_hz=100.0)
    assert s.scored.sum() == 850 - 50
    assert s.heading_rms_deg == pytest.approx(10.0) and s.inclination_rms_deg == pytest.approx(0.0, abs=1e-6)
    assert s.heading_offset_deg == pytest.approx(10.0)
    assert s.heading_rms_offset_removed_deg == pytest.approx(0.0, abs=1e-6)
    assert np.isnan(s.heading_deg[120]) and s.t_s[100] == pytest.approx(1.0)
    q_est[60] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        error_series(q_est, q_ref, movement, rate_hz=100.0)
    with pytest.raises(ValueError, match="no sample"):
        error_series(q_est, q_ref, np.zeros(1000, bool), rate_hz=100.0)


def test_reader_rejects_bad_files(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        read_broad(tmp_path / "missing.mat")
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"not a mat file at all" * 10)
    with pytest.raises(RecordingError, match="junk.mat"):
        read_broad(junk)
    junk.write_text("x")  # scipy calls this one truncated
    with pytest.raises(RecordingError, match="junk.mat"):
        read_broad(junk)
    n = 20
    good = {"imu_gyr": np.zeros((n, 3)), "imu_acc": np.tile([0, 0, 9.81], (n, 1)), "imu_mag": np.ones((n, 3)),
            "opt_quat": np.tile([1.0, 0, 0, 0], (n, 1)), "opt_pos": np.zeros((n, 3)),
            "movement": np.r_[np.zeros(5), np.ones(15)].astype(np.uint8), "sampling_rate": 100.0}
    savemat(tmp_path / "ok.mat", good)
    assert len(read_broad(tmp_path / "ok.mat")) == n
    cases = {"no_mag": ({k: v for k, v in good.items() if k != "imu_mag"}, "missing imu_mag"),
             "quat": (good | {"opt_quat": np.tile([2.0, 0, 0, 0], (n, 1))}, "row 1, column 'opt_quat'"),
             "nan_mag": (good | {"imu_mag": np.r_[np.ones((3, 3)), [[np.nan] * 3], np.ones((16, 3))]},
                         "row 4, column 'imu_mag'"),
             "shape": (good | {"imu_acc": np.zeros((n, 2))}, "column 'imu_acc'"),
             "still": (good | {"movement": np.zeros(n, np.uint8)}, "no sample marked"),
             "rate": (good | {"sampling_rate": -1.0}, "the rate must be a number in \\[0.001, 100000\\] Hz")}
    for name, (content, message) in cases.items():
        savemat(tmp_path / f"{name}.mat", content)
        with pytest.raises(RecordingError, match=message):
            read_broad(tmp_path / f"{name}.mat")


def _crop(src: Path, dst: Path, seconds: float) -> Path:
    """A shorter copy of a BROAD trial (same variables), to keep the end-to-end test fast."""
    from scipy.io import loadmat

    d = loadmat(src, squeeze_me=True)
    n = int(seconds * float(d["sampling_rate"]))
    out = {k: (v[:n] if k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement") else v)
           for k, v in d.items() if not k.startswith("__")}
    savemat(dst, out)
    return dst


MAGNET = BROAD / "32_disturbed_attached_magnet_1cm.mat"


@pytest.mark.skipif(not MAGNET.exists(), reason=f"BROAD data not found at {BROAD}")
def test_evaluate_cli_end_to_end(tmp_path, capsys):
    from compass.cli import main

    # the magnet is attached at about 38 s, movement starts at 41 s: 75 s hold one hard-iron step
    trial = _crop(MAGNET, tmp_path / "magnet.mat", 75.0)
    assert main(["evaluate", str(trial), "--plot", str(tmp_path / "plots")]) == 0
    out = capsys.readouterr().out
    assert "BROAD metric" in out and "offset kept" in out and "removed" in out
    heading = float(out.split("heading RMS ")[1].split()[0])
    inclination = float(out.split("inclination RMS ")[1].split()[0])
    assert heading < 10.0 and inclination < 5.0  # without the step tracker this trial is far off (see docs/benchmarks.md, table 1)
    step = out.split("hard-iron steps: ")[1].splitlines()[0]
    z = float(step.split("(")[1].split(")")[0].split(",")[2])
    assert 45 < z < 70  # the magnet's field along body z, about 58 uT from the reference
    assert (tmp_path / "plots" / "magnet_errors.png").stat().st_size > 10_000


def test_evaluate_cli_bad_input(tmp_path, capsys):
    from compass.cli import main

    assert main(["evaluate", str(tmp_path / "missing.mat")]) == 2
    assert "missing.mat" in capsys.readouterr().err
    (tmp_path / "junk.mat").write_text("junk")
    assert main(["evaluate", str(tmp_path / "junk.mat")]) == 2
    cal = tmp_path / "cal.json"
    cal.write_text('{"format": "something-else/9"}')
    assert main(["evaluate", str(tmp_path / "junk.mat"), "--cal", str(cal)]) == 2
    assert "unknown calibration format" in capsys.readouterr().err
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["evaluate", str(tmp_path / "junk.mat"), "--plot", str(afile)]) == 2
    assert "is a file" in capsys.readouterr().err


def test_rest_noise_measures_injected_white_noise():
    """evaluation.rest_noise (bench_broad's noise table): white noise of known size on a still sensor comes
    back within its sampling scatter (std of n samples: relative 1/sqrt(2 n) per axis, median of three)."""
    from compass.evaluation import rest_noise

    rng = np.random.default_rng(5)
    rate_hz, n = 286.0, 2000  # BROAD's rate; 1000 samples in the first half of the rest
    gyro_density, accel_sigma, mag_sigma = 1e-4, 0.05, 0.7  # rad/s/sqrt(Hz), m/s^2, uT
    gyro = rng.normal(0.0, gyro_density * np.sqrt(rate_hz), (n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, accel_sigma, (n, 3))
    mag = np.array([20.0, 0.0, -45.0]) + rng.normal(0.0, mag_sigma, (n, 3))
    still = np.r_[np.ones(n, bool), np.zeros(10, bool)]
    got = rest_noise(np.r_[gyro, gyro[:10]], np.r_[accel, accel[:10]], np.r_[mag, mag[:10]], still, rate_hz)
    tolerance = 4.0 / np.sqrt(2 * n // 2)  # 4 sigma of one axis' relative scatter
    assert got.samples == n // 2
    assert got.gyro_noise == pytest.approx(gyro_density, rel=tolerance)
    assert got.accel_noise == pytest.approx(accel_sigma / 9.81, rel=tolerance)
    assert got.mag_noise == pytest.approx(mag_sigma, rel=tolerance)
    with pytest.raises(ValueError, match="at least 20 samples at rest"):
        rest_noise(gyro, accel, mag, np.r_[np.ones(10, bool), np.zeros(n - 10, bool)], rate_hz)


@pytest.mark.skipif(not MAGNET.exists(), reason=f"BROAD data not found at {BROAD}")
def test_evaluate_several_trials_by_pattern_prints_each_and_a_table(tmp_path, capsys):
    from compass.cli import main

    for name in ("one", "two"):
        _crop(MAGNET, tmp_path / f"{name}.mat", 45.0)
    assert main(["evaluate", str(tmp_path / "*.mat")]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.strip().startswith(("one ", "two "))]
    assert out.count("  heading RMS ") == 2 and "2 trials:" in out and [r[0] for r in rows] == ["one", "two"]
    assert rows[0][1:] == rows[1][1:]  # the same data, the same scores
