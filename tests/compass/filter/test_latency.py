"""A magnetometer that reads late against the gyro: the filter turns the field forward by the gyro's rotation
over the latency (``FilterConfig.mag_latency_s``), read from a tumble file's gyro-aided fit.

Sign, on paper: the gyro reads ``w``, the rate of H in H (``dR/dt = R [w]x`` with ``R = R_world<-H``); a
world-fixed field seen in H is ``h = R^T b_W``, so ``dh/dt = -[w]x h = h x w``.  A magnetometer ``tau``
late reads ``m = h(t - tau)``, hence ``h(t) = m + tau (m x w)`` to first order: the tumble fit's
``u(t - tau) = (I + tau [w]x) u(t)`` (calibrate/tumble/gyro.py) read the other way.
"""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import FilterConfig, run_filter
from compass.frames import world_field

FIELD_UT, DIP_DEG, RATE_HZ, LATE_S = 50.0, 60.0, 100.0, 0.02
RATE_RAD_S = np.array([0.4, -0.3, 1.6])  # constant, in H: about a tilted axis, 95 deg/s
MAG_NOISE_UT = 0.1


def _recording(late_s, seed=0, seconds=30.0):
    """Constant-rate rotation: exact gyro and accelerometer (a pure rotation about the sensor), the field
    ``late_s`` late plus white noise (the same draws for every ``late_s``); the true ``R_world<-H`` of every row."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    start = Rotation.from_euler("ZYX", [20.0, 10.0, -15.0], degrees=True)

    def attitude(times):
        return start * Rotation.from_rotvec(np.outer(times, RATE_RAD_S))

    truth = attitude(t)
    accel = truth.apply([0.0, 0.0, 9.81], inverse=True)
    field = attitude(t - late_s).apply(world_field(DIP_DEG, FIELD_UT), inverse=True)
    field += rng.normal(0.0, MAG_NOISE_UT, field.shape)
    return t, accel, np.tile(RATE_RAD_S, (len(t), 1)), field, truth


def _heading_errors_deg(track, truth):
    est = Rotation.from_quat(track.quat)
    err = (est * truth.inv()).as_rotvec(degrees=True)[:, 2]  # about the world's vertical, signed
    return err[len(err) // 2:]  # the second half: settled


def _run(late_s, tau):
    t, accel, gyro, field, truth = _recording(late_s)
    config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, mag_latency_s=tau)
    return _heading_errors_deg(run_filter(t, accel, gyro, field, config, reference="config"), truth)


def test_a_late_magnetometer_biases_the_heading_and_the_compensation_removes_it():
    lag_deg = np.degrees(np.linalg.norm(RATE_RAD_S) * LATE_S)  # the field's turn over the latency, 1.9 deg
    on_time = _run(0.0, 0.0)  # the filter's own error in this fast turn, the reference
    late, compensated = _run(LATE_S, 0.0), _run(LATE_S, LATE_S)
    bias = np.mean(late - on_time)
    assert abs(bias) > 0.5 * lag_deg  # the latency's heading bias is there
    # compensated, the heading is the on-time one's to within the noise: the same draws, so what is left is the
    # first order's remainder (tau |w|)^2 / 2 (0.03 deg) and the noise turned by tau w (white, averaged out)
    assert abs(np.mean(compensated - on_time)) < 0.05 * abs(bias)
    assert np.sqrt(np.mean((compensated - on_time) ** 2)) < 0.1 * np.sqrt(np.mean((late - on_time) ** 2))
    # a compensation of the other sign would double the bias: the negative latency is refused instead
    with pytest.raises(ValueError, match="mag_latency_s must be a non-negative number"):
        _run(LATE_S, -LATE_S)


def test_the_filter_takes_the_calibrations_latency():
    from compass.sim.device import default_model

    model = dataclasses.replace(default_model(), mag_latency_s=LATE_S)
    assert FilterConfig.from_model(model, mag_latency=True).mag_latency_s == LATE_S
    assert FilterConfig.from_model(model).mag_latency_s == 0.0  # off by default (BROAD: docs/benchmarks.md)
    assert FilterConfig.from_model(default_model(), mag_latency=True).mag_latency_s == 0.0
    with pytest.raises(ValueError, match="mag_latency_s must be a non-negative number"):
        dataclasses.replace(default_model(), mag_latency_s=-0.01)
    # compass live's and the replay's --mag-latency and --gravity
    live = FilterConfig.from_model(model, gravity=9.81)
    assert live.mag_latency_s == 0.0 and live.gravity == 9.81



def _write_recording(path, model, t, s):
    """The simulated device's samples ``s`` at times ``t`` as a recording CSV (raw channels, accelerometer, gyro)."""
    from compass.io.table import format_table

    columns = ({"t_s": t} | {c: s.raw[:, k] for k, c in enumerate(model.channels)}
               | {c: s.accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
               | {c: s.gyro[:, k] for k, c in enumerate(("gx", "gy", "gz"))})
    path.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    return path


def attitude_and_live_rows(tmp_path, cal, rec, model, t, s, option, config):
    """Rows (every column but latency_ms, the processing time) of ``compass attitude CAL REC --filter``, with
    ``option`` when given, and of a live session with ``config`` replaying the same samples ``s`` at ``t``:
    asserted identical, returned."""
    import io

    from compass.cli import main
    from compass.live import LiveSession
    from compass.replay import replay

    def rows(text):
        lines = [line.split(",") for line in text.splitlines() if line and not line.startswith(("#", "t_s"))]
        return [line[:12] for line in lines]

    out = tmp_path / f"att_{option}.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--filter"] + ([option] if option else [])) == 0
    session = LiveSession(model, config=config, out=io.StringIO())
    replay(session, t, s.raw, s.accel, s.gyro)
    assert rows(out.read_text()) == rows(session.out.getvalue())
    return rows(out.read_text())


def test_compass_attitude_filter_mag_latency_compensates_the_files_latency(tmp_path, capsys):
    """``--mag-latency`` (live and the replay alike): the file's fitted latency reaches the filter; without it, none."""
    from calibrate.tumble import calibrate_tumble
    from compass.calibration import from_dict, save
    from compass.cli import main
    from compass.sim.device import simulate_device
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=4, n=1500)
    doc = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).to_json()
    doc["tumble"]["gyro"] = {"method": "gyro", "used": True, "mag_latency_s": LATE_S, "mag_latency_sigma_s": 1e-4}
    cal = save(tmp_path / "cal.json", doc)
    model = from_dict(doc).model
    assert model.mag_latency_s == LATE_S
    t = np.arange(0.0, 15.0, 0.01)
    s = simulate_device(model, t, seed=6)
    rec = _write_recording(tmp_path / "rec.csv", model, t, s)

    outputs = {}
    for flag in (True, False):
        capsys.readouterr()
        outputs[flag] = attitude_and_live_rows(tmp_path, cal, rec, model, t, s, "--mag-latency" if flag else None,
                                               FilterConfig.from_model(model, mag_latency=flag))
        assert ("turned forward by the gyro over the magnetometer's 20.0 ms latency" in capsys.readouterr().err) == flag
    assert outputs[True] != outputs[False]
    capsys.readouterr()
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv"), "--mag-latency"]) == 2
    assert "--mag-latency goes with --filter" in capsys.readouterr().err


def test_mag_latency_says_when_there_is_nothing_to_compensate(tmp_path, capsys):
    """``--mag-latency`` with a calibration whose fit saw no latency (here a four-flip-like model) or on a
    recording without a gyro: exit 0, and a warning saying nothing was compensated."""
    import json

    from compass.calibration import model_to_dict
    from compass.cli import main
    from compass.replay import mag_latency_note
    from compass.sim.device import default_model, simulate_device

    model = default_model()
    assert mag_latency_note(model)[0] == "warn" and "nothing compensated" in mag_latency_note(model)[1]
    assert mag_latency_note(dataclasses.replace(model, mag_latency_s=LATE_S), has_gyro=False)[0] == "warn"
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    t = np.arange(0.0, 5.0, 0.01)
    s = simulate_device(model, t, seed=2)
    rec = _write_recording(tmp_path / "rec.csv", model, t, s)
    capsys.readouterr()
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv"), "--filter", "--mag-latency"]) == 0
    assert "[warn] --mag-latency: the calibration holds no magnetometer latency" in capsys.readouterr().err
